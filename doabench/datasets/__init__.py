"""Datasets: generate, inspect, merge, load and replay HDF5 files of precomputed episodes.

* :func:`make_dataset` (``doabench make-dataset``): a task's episodes -> one HDF5 file, schema
  ``doabench.dataset/1`` (docs/hdf5-schema.md), resumable and safe against SIGKILL;
* :class:`DatasetFile` (``doabench dataset info``): read a file;
* :func:`merge_datasets` (``doabench dataset merge``): join shards;
* :class:`EpisodeDataset`: a ``torch.utils.data.Dataset`` of per-episode tensors for training;
* ``--task file:data.h5``: replay a file as a task (kind ``dataset``); the ``file:`` prefix and the
  kind are declared in pyproject.toml (entry-point groups ``doabench.task_prefixes`` and
  ``doabench.task_kinds``) and loaded by the task registry when first asked for.
"""
from __future__ import annotations

from doabench.datasets.generate import GenerationResult, make_dataset
from doabench.datasets.merge import merge_datasets
from doabench.datasets.reader import DatasetFile
from doabench.datasets.replay import DatasetEpisodes, resolve_file_task
from doabench.datasets.schema import SCHEMA, parse_features
from doabench.datasets.torch_dataset import EpisodeDataset

__all__ = ["SCHEMA", "DatasetEpisodes", "DatasetFile", "EpisodeDataset", "GenerationResult", "make_dataset",
           "merge_datasets", "parse_features", "resolve_file_task"]
