"""NDI passive tools shipped with the package: marker geometries and ``.rom`` tool definition files.

The image side (marker-sphere size), the navigation logic (marker centres in the reference body's frame), the
simulation and the tracker feed (``.rom`` files loaded into the tracker) all read them from here.
Geometries typed from PLUS Toolkit's PlusLibData ``.rom`` files (BSD-3-Clause, see ``data/licenses``).
"""

import json
from pathlib import Path

import numpy as np

DATA_DIR = Path(__file__).resolve().parent / "data"

#: NDI reference body used by the demo: passive 4-marker tool 8700339.
DEFAULT_REFERENCE_TOOL = "8700339"

#: NDI passive probe (pointer) used by the simulator and the tracker server: tool 8700340.
DEFAULT_PROBE_TOOL = "8700340"

#: NDI passive tool whose markers are fixed to the robot's cutting tool in the simulations (tracked as ToolToTracker).
DEFAULT_CUTTING_TOOL = "8700449"

#: Diameter of NDI passive marker spheres (mm), as in the paper.
MARKER_DIAMETER_MM = 11.5


def _tools():
    return json.loads((DATA_DIR / "ndi_passive_tools.json").read_text(encoding="utf-8"))["tools"]


def tool_marker_geometry(tool_id=DEFAULT_REFERENCE_TOOL):
    """Marker centres (K, 3) in mm in the NDI tool's own frame, from ``ndi_passive_tools.json``."""
    tools = _tools()
    if tool_id not in tools:
        raise ValueError(f"NDI tool {tool_id!r}: known tools are {', '.join(tools)}")
    return np.array(tools[tool_id]["markers"], dtype=np.float64)


def tool_rom_path(tool_id):
    """Path of a shipped NDI tool definition file (``<tool_id>.rom``), as loaded into the tracker with PVWR."""
    path = DATA_DIR / f"{tool_id}.rom"
    if not path.is_file():
        shipped = sorted(rom.stem for rom in DATA_DIR.glob("*.rom"))
        raise ValueError(f"NDI tool {tool_id!r}: shipped .rom files are {', '.join(shipped)}")
    return path
