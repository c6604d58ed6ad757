"""Validation against the normative SSP 1.0 XML schemas (Modelica Association, shipped in
fmpy's ``fmpy/ssp/schema/``: SystemStructureDescription.xsd, ...ParameterValues.xsd and the
common definitions they import), with lxml."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from lxml import etree

import fmpy

SCHEMA_DIR = Path(fmpy.__file__).parent / "ssp" / "schema"
SSD_XSD = "SystemStructureDescription.xsd"
SSV_XSD = "SystemStructureParameterValues.xsd"
NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues"}


@lru_cache(maxsize=4)
def schema(name: str) -> etree.XMLSchema:
    """The compiled XML schema ``name`` (a file in SCHEMA_DIR)."""
    return etree.XMLSchema(etree.parse(str(SCHEMA_DIR / name)))


def problems(root: etree._Element, name: str) -> list[str]:
    """Schema violations of ``root`` against schema ``name``: ``"line L: message"`` each (empty: valid)."""
    xsd = schema(name)
    if xsd.validate(root):
        return []
    return [f"line {e.line}: {e.message}" for e in xsd.error_log]
