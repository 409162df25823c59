"""Batch reprocessing of whole surveys on Dask distributed (``svss batch``,
docs/batch.md): :mod:`.plan` plans every run's tiles from its ping and pose tables,
:mod:`.task` images one tile from its raw files, :mod:`.run` runs the tasks on a
cluster, resumes and summarises. Dask is imported only when a batch runs.
"""
