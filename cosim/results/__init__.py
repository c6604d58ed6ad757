"""Run results: summary.json, streamed time-series files and the progress bar."""
from cosim.results.progress import ProgressBar
from cosim.results.summary import SummaryWriter
from cosim.results.timeseries import CsvSink, read_csv

__all__ = ["CsvSink", "ProgressBar", "SummaryWriter", "read_csv"]
