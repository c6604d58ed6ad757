"""SSP (System Structure and Parameterization 1.0) export and import of a co-simulation.

``export_document(fmus, connections, out, ...)`` writes FMUs, connections and parameter values
as one ``.ssp`` archive: ``SystemStructure.ssd`` (components, connectors, connections, the
default experiment), one ``.ssv`` parameter set per instance, all named ``PARAMETER_SET``,
and the FMUs themselves in ``resources/``. FMU inputs driven by the Python side (master
variables: the controller's CiA 402 telegrams over the emulated POWERLINK bus, the laser
tracker) carry an annotation naming the master variable and who drives it; every SSD
connection joins two components, so libcosim and Ecos load and run the archive as it is.
``load_ssp(path)`` reads such an archive back (validated against the SSP 1.0 XML schemas
that ship with fmpy) into ``[[fmus]]`` tables and connections for the master. docs/how-to/ssp.md
says what the export leaves out.
"""
from cosim.ssp.errors import SspError
from cosim.ssp.read import SspSystem, load_ssp
from cosim.ssp.write import PARAMETER_SET, export_document

__all__ = ["PARAMETER_SET", "SspError", "SspSystem", "export_document", "load_ssp"]
