"""Run results: summary.json, streamed time-series files (Parquet or CSV) and the progress bar."""
from cosim.results.progress import ProgressBar
from cosim.results.summary import SummaryWriter
from cosim.results.timeseries import CsvSink, ParquetSink, read_csv, read_series, read_units, write_columns

__all__ = ["CsvSink", "ParquetSink", "ProgressBar", "SummaryWriter", "read_csv", "read_series", "read_units",
           "write_columns"]
