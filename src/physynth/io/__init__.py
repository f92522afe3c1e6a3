"""Reading and writing datasets, importing real recordings."""

from .dataset import Dataset, DatasetWriter, read_dataset, read_meta, write_dataset

__all__ = ["Dataset", "DatasetWriter", "read_dataset", "read_meta", "write_dataset"]
