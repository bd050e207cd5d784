"""The quality-control report: decisions, group sigmas, offsets/drifts per round, as a Dataset and a table."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from ...atomic import atomic_write
from ...errors import QualityControlInputError

__all__ = ["QCReport"]

#: the table names the group another trades with when their variance factors correlate below minus this
SEPARABLE_CORRELATION = 0.8

_FIELDS = ("step", "round", "kind", "index", "image", "point", "component", "value", "redundancy", "action", "group",
           "term")


@dataclass
class QCReport:
    """What a quality-controlled adjustment did (:func:`~lunarmap.adjust.qc.quality_control`).

    Attributes
    ----------
    decisions : list of Decision
        Every observation removed, down-weighted or flagged, points dropped, images fixed.
    groups : xarray.Dataset or None
        Per observation group: ``sigma_factor`` (estimated sigma / a-priori sigma) with its standard
        deviation, ``redundancy``, ``observations`` (variance components); for blocks small enough, the
        standard deviation from the joint covariance of all groups (``sigma_factor_sigma_joint``) and the
        groups' ``correlation`` (near -1: groups the data cannot separate); absent if not estimated.
    offsets : list of xarray.Dataset
        The offset/drift detection rounds (``"times 1"``, ``"times 2"``, ``"results"``).
    status : xarray.Dataset or None
        The final status of every observation (:func:`~lunarmap.adjust.qc.status.final_status`):
        read it with :meth:`final_status`.
    summary : dict
        ``steps``, ``first_adjustment`` (``"least squares"``, or ``"robust"`` when the robust step
        comes first), ``sigma0_first`` / ``sigma0_last`` (a-posteriori sigma0 of the first and last
        adjustments), ``untestable`` observations of the last data-snooping round, ``max_w``; ``clean``
        (False when the run ended without a clean block) and ``flags`` (why: :mod:`.ending`).
    """

    decisions: list = field(default_factory=list)
    groups: xr.Dataset | None = None
    offsets: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    status: xr.Dataset | None = None

    def final_status(self) -> xr.Dataset:
        """The final status of every observation: ``in``, ``removed``, ``down-weighted``, ``withdrawn`` or
        ``set-aside``, with the deciding step, round, test value and reason (see
        :func:`~lunarmap.adjust.qc.status.final_status` for the fields).

        Raises
        ------
        QualityControlInputError
            A report built without the table (by hand, not by :func:`~lunarmap.adjust.qc.quality_control`).
        """
        if self.status is None:
            raise QualityControlInputError("this QC report has no final status table (it was not made by "
                                           "quality_control)")
        return self.status

    @property
    def clean(self) -> bool:
        """False when quality control ended without a clean block (``summary["flags"]`` say why)."""
        return bool(self.summary.get("clean", True))

    def status_counts(self) -> dict:
        """Observations per (kind, final status), e.g. ``{("image", "removed"): 23, ...}``."""
        if self.status is None:
            return {}
        out: dict[tuple[str, str], int] = {}
        for k, st in zip(self.status["kind"].values, self.status["status"].values):
            out[(str(k), str(st))] = out.get((str(k), str(st)), 0) + 1
        return out

    def counts(self) -> dict:
        """Observations acted on per (step, kind, action)."""
        out: dict[tuple[str, str, str], int] = {}
        for d in self.decisions:
            key = (d.step, d.kind, d.action)
            out[key] = out.get(key, 0) + 1
        return out

    def to_dataset(self) -> xr.Dataset:
        """Everything as one xarray Dataset: dimensions ``decision`` (the decisions' fields), ``status_row``
        (``status_*``: :meth:`final_status`), ``obs_group``
        (``group_*`` variables; ``acted_on (obs_group, qc_step)`` counts observations removed, down-weighted,
        flagged or withdrawn per group and step) and ``offset_row`` (``offset_*``, every round)."""
        text = {"step", "kind", "action", "group"}
        ds = xr.Dataset({f: ("decision", np.array([getattr(d, f) for d in self.decisions],
                                                  dtype=object if f in text else float if f in ("value", "redundancy")
                                                  else np.int64)) for f in _FIELDS},
                        coords={"decision": np.arange(len(self.decisions))})
        if self.groups is not None:
            g = self.groups.rename({k: f"group_{k}" for k in self.groups.data_vars}).rename({"group": "obs_group"})
            if "group_other" in g.dims:
                g = g.rename({"group_other": "obs_group_other"})
            ds = ds.merge(g)
            steps = sorted({d.step for d in self.decisions})
            names = list(self.groups["group"].values)
            tab = np.zeros((len(names), len(steps)), np.int64)
            for d in self.decisions:
                if d.group in names and d.action in ("removed", "downweighted", "flagged", "withdrawn"):
                    tab[names.index(d.group), steps.index(d.step)] += 1
            ds["acted_on"] = (("obs_group", "qc_step"), tab)
            ds = ds.assign_coords(qc_step=np.array(steps, dtype=object))
        if self.offsets:
            rows = []
            for r in self.offsets:
                rr = r.assign(round=("row", np.full(r.sizes.get("row", 0), r.attrs["round"], dtype=object)))
                rows.append(rr)
            off = xr.concat(rows, dim="row").rename({"row": "offset_row"})
            off = off.rename({k: f"offset_{k}" for k in off.data_vars})
            ds = ds.merge(off)
        if self.status is not None:
            st = self.status.rename({k: f"status_{k}" for k in self.status.data_vars})
            ds = ds.merge(st.rename({"observation": "status_row"}))
        ds.attrs.update(_netcdf_attrs(self.summary))
        return ds

    def write(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_dataset` to a netCDF file atomically (nothing is left behind on failure).

        Raises
        ------
        QualityControlInputError
            The folder does not exist.
        """
        path = Path(path)
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise QualityControlInputError(f"cannot write the QC report {path}: folder {folder} does not exist")
        ds = self.to_dataset()
        for k in list(ds.variables):
            if ds[k].dtype == object:
                ds[k] = ds[k].astype(str)
        return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4"))

    def table(self) -> str:
        """A printable summary: actions per step and group, group sigmas, offsets/drifts per round."""
        lines = []
        s = self.summary
        first = f" ({s['first_adjustment']})" if s.get("first_adjustment") else ""
        lines.append(f"quality control: steps {' -> '.join(s.get('steps', []))}; sigma0 first{first} "
                     f"{s.get('sigma0_first', float('nan')):.3f}, last {s.get('sigma0_last', float('nan')):.3f}")
        if not self.clean:
            lines.append("NOT A CLEAN BLOCK: " + "; ".join(map(str, s.get("flags", []))))
        sc = self.status_counts()
        if sc:
            lines.append("final status: " + ", ".join(f"{kind} {st} {n}" for (kind, st), n in sorted(sc.items())))
        c = self.counts()
        if c:
            lines.append(f"{'step':<9} {'kind':<11} {'action':<13} {'count':>5}")
            for (step, kind, action), n in sorted(c.items()):
                lines.append(f"{step:<9} {kind:<11} {action:<13} {n:>5}")
        tested = [d for d in self.decisions if d.step in ("baarda", "robust", "sequent") and d.action != "dropped"]
        if tested:
            lines.append(f"{'step':<8} {'rnd':>4} {'kind':<10} {'index':>6} {'image':>5} {'point':>5} {'comp':>4} "
                         f"{'value':>10} {'r':>6}  action")
            for d in tested:
                lines.append(f"{d.step:<8} {d.round:>4} {d.kind:<10} {d.index:>6} {d.image:>5} {d.point:>5} "
                             f"{d.component:>4} {d.value:>10.3g} {d.redundancy:>6.3f}  {d.action} ({d.group})")
        if self.groups is not None:
            g = self.groups
            joint = "correlation" in g
            lines.append(f"{'group':<36} {'sigma after/before':>18} {'+-':>7} {'redundancy':>10} {'obs':>5}"
                         + (f" {'+- joint':>8}  trades with" if joint else ""))
            for i, name in enumerate(g["group"].values):
                tail = "" if bool(g["estimated"].values[i]) else "  (not estimated)"
                if joint:
                    corr = np.array(g["correlation"].values[i], float)
                    corr[i] = 0.0
                    j = int(np.nanargmin(corr)) if np.isfinite(corr).any() else -1
                    trade = (f" {g['group'].values[j]} ({corr[j]:+.2f})" if j >= 0 and corr[j] < -SEPARABLE_CORRELATION
                             else "")
                    tail = f" {float(g['sigma_factor_sigma_joint'].values[i]):>8.4f} {trade}" + tail
                lines.append(f"{str(name):<36} {float(g['sigma_factor'].values[i]):>18.4f} "
                             f"{float(g['sigma_factor_sigma'].values[i]):>7.4f} {float(g['redundancy'].values[i]):>10.1f} "
                             f"{int(g['observations'].values[i]):>5}{tail}")
        for r in self.offsets:
            lines.append(f"offsets/drifts, {r.attrs['round']}:")
            for i in range(r.sizes.get("row", 0)):
                lines.append(f"  orbit {int(r['orbit'].values[i])} {str(r['param'].values[i]):<6} "
                             f"{str(r['kind'].values[i]):<6} {float(r['value'].values[i]):>12.6g} +- "
                             f"{float(r['sigma'].values[i]):<10.3g} {'free' if r['free'].values[i] else '    '} "
                             f"{'significant' if r['significant'].values[i] else ''}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


def _netcdf_attrs(summary: dict, prefix: str = "") -> dict:
    """The summary as netCDF attributes: nested dicts flattened to ``outer_inner`` names, booleans as
    0/1 and None as "none" (netCDF has neither), lists joined into one string."""
    out: dict = {}
    for k, v in summary.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_netcdf_attrs(v, f"{name}_"))
            continue
        if isinstance(v, bool):
            v = int(v)
        elif v is None:
            v = "none"
        elif isinstance(v, (list, tuple)):
            v = ("; " if k == "flags" else ", ").join(map(str, v))
        out[name] = v
    return out
