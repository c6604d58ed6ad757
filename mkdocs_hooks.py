"""MkDocs hooks of the docs site (mkdocs.yml ``hooks:``): the reference pages generated from the code.

At each build, ``on_files`` adds to the site, without writing into docs/:

* ``reference/scenario_keys.md``: every key of every job type, from the schemas
  (:func:`cosim.scenario.reference.scenario_keys_markdown`), and every key of a sweep file
  (:func:`sweep_keys_markdown`, from ``cosim.sweep.loader.SWEEP_SCHEMA``);
* ``reference/cli.md``: every command and argument, from argparse
  (:func:`cosim.cli_reference.cli_markdown`);
* ``reference/benchmarks.md``: ``benchmarks/RESULTS.md``, the results page ``python -m cosim
  bench`` writes (every figure of its last full run, with the machine, its load and the date).

and ``on_page_markdown`` puts tables built from the code into hand-written pages in place of
their marker lines (:data:`MARKERS`): the object table of ``fieldbus/object_dictionary.toml``
(axis 1, :func:`fieldbus.device_files.reference_markdown`) into ``reference/object_dictionary.md``
(:data:`OBJECT_DICTIONARY_MARKER`); the identifiers, telegram layouts and udpcycle datagram
layout (:mod:`fieldbus.reference`) into ``reference/fieldbus.md`` (:data:`FIELDBUS_MARKERS`); the
tables of exit codes, violation kinds and drive protection limits into ``reference/verdicts.md``
(:func:`cosim.verdict_reference.fill`); and the drive FMU interface
(:func:`fmus.servo_drive.interface.reference_markdown`) into ``how-to/own_drive.md``
(:data:`DRIVE_INTERFACE_MARKER`).

The checkout holding this file is put first on ``sys.path``, so the pages describe its code
(not another installed copy).
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

def sweep_keys_markdown() -> str:
    """The section of the scenario-key page listing every key of a sweep file."""
    from cosim.scenario.reference import table_keys_markdown
    from cosim.sweep.loader import SWEEP_SCHEMA

    return ("\n## Sweep files {#sweep-file}\n\n"
            "The keys of a sweep file (`cosim sweep`, [Run a sweep on a cluster](../how-to/sweep_cluster.md)),\n"
            "generated from `cosim.sweep.loader.SWEEP_SCHEMA`. `[overrides]` keys and `[[axes]] key` are key\n"
            "paths of the base scenario's keys above.\n\n" + table_keys_markdown(SWEEP_SCHEMA))


#: site path -> (function building the page's Markdown)
GENERATED = {
    "reference/scenario_keys.md": lambda: (__import__("cosim.scenario.reference", fromlist=["_"]).scenario_keys_markdown()
                                           + sweep_keys_markdown()),
    "reference/cli.md": lambda: __import__("cosim.cli_reference", fromlist=["_"]).cli_markdown(),
    "reference/benchmarks.md": lambda: (ROOT / "benchmarks" / "RESULTS.md").read_text(encoding="utf-8"),
}


def on_files(files, config):
    from mkdocs.structure.files import File

    for uri, build in GENERATED.items():
        files.append(File.generated(config, uri, content=build()))
    return files


#: the line of docs/reference/object_dictionary.md the generated object table replaces
OBJECT_DICTIONARY_MARKER = "<!-- generated: the table of fieldbus/object_dictionary.toml, axis 1 (mkdocs_hooks.py) -->"


def object_dictionary_markdown(markdown: str) -> str:
    """``markdown`` with the marker line replaced by the object table of axis 1's drive."""
    from fieldbus.device_files import reference_markdown
    from fmus.servo_drive.object_dictionary import drive_object_dictionary

    if OBJECT_DICTIONARY_MARKER not in markdown:
        raise ValueError(f"reference/object_dictionary.md: the marker {OBJECT_DICTIONARY_MARKER!r} is missing")
    return markdown.replace(OBJECT_DICTIONARY_MARKER, reference_markdown(drive_object_dictionary(1)))


def _axis1_dictionary():
    from fmus.servo_drive.object_dictionary import drive_object_dictionary

    return drive_object_dictionary(1)


#: marker line of docs/reference/fieldbus.md -> the function building the table that replaces it
FIELDBUS_MARKERS = {
    "<!-- generated: fieldbus.reference.identifiers_markdown (mkdocs_hooks.py) -->":
        lambda: __import__("fieldbus.reference", fromlist=["_"]).identifiers_markdown(),
    "<!-- generated: fieldbus.reference.telegrams_markdown (mkdocs_hooks.py) -->":
        lambda: __import__("fieldbus.reference", fromlist=["_"]).telegrams_markdown(_axis1_dictionary()),
    "<!-- generated: fieldbus.reference.udpcycle_options_markdown (mkdocs_hooks.py) -->":
        lambda: __import__("fieldbus.reference", fromlist=["_"]).udpcycle_options_markdown(),
    "<!-- generated: fieldbus.reference.udpcycle_markdown (mkdocs_hooks.py) -->":
        lambda: __import__("fieldbus.reference", fromlist=["_"]).udpcycle_markdown(),
}


def fieldbus_markdown(markdown: str) -> str:
    """``markdown`` with each of :data:`FIELDBUS_MARKERS` replaced by its generated table."""
    for marker, build in FIELDBUS_MARKERS.items():
        if markdown.count(marker) != 1:
            raise ValueError(f"reference/fieldbus.md: the marker {marker!r} must appear once")
        markdown = markdown.replace(marker, build())
    return markdown


#: the line of docs/how-to/own_drive.md the generated drive interface table replaces
DRIVE_INTERFACE_MARKER = "<!-- generated: the table of fmus.servo_drive.interface.DRIVE_INTERFACE (mkdocs_hooks.py) -->"


def drive_interface_markdown(markdown: str) -> str:
    """``markdown`` with the marker line replaced by the table of the drive FMU interface."""
    from fmus.servo_drive.interface import reference_markdown

    if DRIVE_INTERFACE_MARKER not in markdown:
        raise ValueError(f"how-to/own_drive.md: the marker {DRIVE_INTERFACE_MARKER!r} is missing")
    return markdown.replace(DRIVE_INTERFACE_MARKER, reference_markdown())


#: page -> the function putting its generated table in place of its marker
MARKERS = {
    "reference/object_dictionary.md": object_dictionary_markdown,
    "reference/fieldbus.md": fieldbus_markdown,
    "how-to/own_drive.md": drive_interface_markdown,
    "reference/verdicts.md": lambda markdown: __import__("cosim.verdict_reference", fromlist=["_"]).fill(markdown),
}


def on_page_markdown(markdown, page, config, files):
    fill = MARKERS.get(page.file.src_uri)
    return fill(markdown) if fill else markdown
