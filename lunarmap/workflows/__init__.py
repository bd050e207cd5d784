"""Workflows: the whole chain of a run configuration as one dask graph, resumable, with progress and a report.

* :func:`run` -- TOML configuration (:func:`load_config`) -> ISDs, RPCs, tie points, adjustment, adjusted
  kernels, report, in a run folder (:class:`RunResult`); serial, on a local cluster or on a running
  ``dask scheduler``;
* :func:`write_example` -- the embedded example: a synthetic mission with rendered images and its
  configuration (``lunarmap run --example``).
"""

from .config import ImageSpec, NavigationConfig, RunConfig, config_from_dict, load_config
from .engine import STAGES, RunPlan, RunResult, build_graph, plan, run
from .example import write_example
from .store import Store, file_digest, step_key

__all__ = ["run", "plan", "RunPlan", "RunResult", "RunConfig", "ImageSpec", "NavigationConfig", "load_config", "config_from_dict",
           "write_example", "build_graph", "STAGES", "Store", "file_digest", "step_key"]
