"""Bone meshes shipped inside the package (installed with it, so the demo runs after a plain pip install).

Visible Human Female tibiae and right fibula (University of Denver, CC BY 4.0) and a right ilium (the right hip
bone from the lowest slice of its CT up to the iliac crest) made smooth from TotalSegmentator's ``hip_right``
mask of its example CT (Apache-2.0, by ``tools/make_ilium_mesh.py``); see ``data/licenses``.
The NDI tool geometries live in ``io.ndi_tools``, where the image side can read them too.
"""

from pathlib import Path

from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL, tool_marker_geometry

DATA_DIR = Path(__file__).resolve().parent / "data"

#: Bone meshes by short name: file, the image direction (RAS) that is lateral for that side, the kind of bone
#: (``VirtualPatient`` places the probe points and the cut by it) and where the mesh comes from, with its licence.
BONES = {
    "right-tibia": {
        "file": "VHF_Right_Bone_Tibia_smooth.stl",
        "lateral": (1.0, 0.0, 0.0),
        "anatomy": "long-bone",
        "source": "the Visible Human Female (CC BY 4.0)",
    },
    "left-tibia": {
        "file": "VHF_Left_Bone_Tibia_smooth.stl",
        "lateral": (-1.0, 0.0, 0.0),
        "anatomy": "long-bone",
        "source": "the Visible Human Female (CC BY 4.0)",
    },
    "right-fibula": {
        "file": "VHF_Right_Bone_Fibula_smooth.stl",
        "lateral": (1.0, 0.0, 0.0),
        "anatomy": "long-bone",
        "source": "the Visible Human Female (CC BY 4.0)",
    },
    "right-ilium": {
        "file": "TotalSegmentator_hip_right_smooth.stl",
        "lateral": (1.0, 0.0, 0.0),
        "anatomy": "flat-bone",
        "source": "TotalSegmentator's example CT (Apache-2.0)",
    },
}


def bone_mesh_path(name):
    """Path of a shipped bone mesh (a key of ``BONES``): untagged RAS mm, or tagged LPS as Slicer writes models."""
    if name not in BONES:
        raise ValueError(f"bone {name!r}: shipped bones are {', '.join(BONES)}")
    return DATA_DIR / BONES[name]["file"]


def bone_mesh(name):
    """Vertices (V, 3) in RAS mm and triangles (K, 3) of a shipped bone mesh."""
    from ..io.surface_files import read_surface_mesh

    return read_surface_mesh(bone_mesh_path(name), untagged_space="RAS")


def shipped_patient(bone="right-tibia", seed=0, mesh=None, **options):
    """A VirtualPatient on a shipped bone with the default NDI reference body.

    Args:
        mesh: the bone's (vertices, triangles) when already read (saves reading the file again).
        options: passed to ``VirtualPatient.from_mesh`` (bracket offset, turn, ...).

    Returns:
        (patient, vertices, triangles).
    """
    from .virtual_patient import VirtualPatient

    vertices, triangles = bone_mesh(bone) if mesh is None else mesh
    patient = VirtualPatient.from_mesh(
        vertices,
        triangles,
        tool_marker_geometry(DEFAULT_REFERENCE_TOOL),
        BONES[bone]["lateral"],
        anatomy=BONES[bone]["anatomy"],
        seed=seed,
        **options,
    )
    return patient, vertices, triangles
