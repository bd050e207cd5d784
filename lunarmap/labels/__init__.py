"""Image labels: ISIS cube labels and PDS3 labels (PVL)."""

from .pvl import Label, Quantity, load_label, parse_label

__all__ = ["Label", "Quantity", "load_label", "parse_label"]
