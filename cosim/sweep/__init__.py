"""Sweeps: parameter studies and Monte Carlo campaigns over a base scenario, run on Dask.

``load_sweep(path)`` validates a sweep file and every variant it generates before
anything runs; ``run_sweep(sweep, out_dir, workers=..., scheduler=...)`` runs the
variants as independent tasks (``run_variant``: the ordinary scenario runner in a
worker process) and writes the table, the figure and each variant's folder.
See docs/how-to/sweep_cluster.md.
"""
from cosim.sweep.axes import Axis
from cosim.sweep.execute import SweepResult, dask_client, run_sweep, variant_tasks
from cosim.sweep.loader import Report, Sweep, Variant, load_sweep, load_sweep_document, variant_hash
from cosim.sweep.task import VariantTask, run_variant

__all__ = ["Axis", "Report", "Sweep", "SweepResult", "Variant", "VariantTask", "dask_client", "load_sweep",
           "load_sweep_document", "run_sweep", "run_variant", "variant_hash", "variant_tasks"]
