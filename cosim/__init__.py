"""Composition root: co-simulation master, scenario runner, CLI and results."""
