"""lunarmap workflows: dask graphs built only from lunarmap's public API.

Each module exposes ``build(...)`` (the dask graph) and ``run(...)`` (build and
compute on a local cluster, or on a dask-distributed scheduler given its address).
"""
