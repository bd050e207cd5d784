"""Image labels: ISIS cube labels and PDS3 labels (PVL)."""

from .isis_table import isis_table_names, read_isis_table
from .pvl import Label, Quantity, load_label, parse_label

__all__ = ["Label", "Quantity", "load_label", "parse_label", "read_isis_table", "isis_table_names"]
