"""MkDocs hooks of the docs site (mkdocs.yml ``hooks:``): the reference pages generated from the code.

At each build, ``on_files`` adds to the site, without writing into docs/:

* ``reference/scenario_keys.md``: every key of every job type, from the schemas
  (:func:`cosim.scenario.reference.scenario_keys_markdown`);
* ``reference/cli.md``: every command and argument, from argparse
  (:func:`cosim.cli_reference.cli_markdown`);
* ``reference/fieldbus.md``: ``fieldbus/README.md`` (the bus, its frames and the udpcycle wire
  format), which lives beside the package it documents.

The checkout holding this file is put first on ``sys.path``, so the pages describe its code
(not another installed copy).
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: site path -> (function building the page's Markdown)
GENERATED = {
    "reference/scenario_keys.md": lambda: __import__("cosim.scenario.reference", fromlist=["_"]).scenario_keys_markdown(),
    "reference/cli.md": lambda: __import__("cosim.cli_reference", fromlist=["_"]).cli_markdown(),
    "reference/fieldbus.md": lambda: (ROOT / "fieldbus" / "README.md").read_text(encoding="utf-8"),
}


def on_files(files, config):
    from mkdocs.structure.files import File

    for uri, build in GENERATED.items():
        files.append(File.generated(config, uri, content=build()))
    return files
