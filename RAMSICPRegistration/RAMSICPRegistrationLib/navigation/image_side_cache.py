"""The image side of a CT processed once and read back: ``ramsicp web --demo`` processes the same demo CT at every
start (segmentation, IPC, marker spheres: 3.3 s at load 5), reading the result back takes a tenth of that.

``cached_image_side`` has ``image.ct_pipeline.process_ct``'s signature and result. The cache is one ``.npz`` per
processed CT in the user's cache folder (``simulation.phantom_cache.cache_directory``), named by a key: the SHA-256
of what the result depends on, i.e. ``IMAGE_SIDE_VERSION`` and the source of the ``image`` package (any change to
how a CT is processed processes it again), the CT's voxels, their type, shape and IJK-to-RAS matrix, the threshold,
``fill_cavities`` and the tool's marker geometry. A file is written whole or not at all (``io.atomic_files``); one
that cannot be read, or holds arrays that do not fit the CT, is made again and replaced. A cache that cannot be
written (read-only home, full disk) costs only the time.

What is read back is the result as the navigation steps use it: the segmentation's labels over the box of the CT
that holds something (stored as the voxels that are not background), that box, the reference body's voxels in the
bone's object, the IPC with what it left out, the spheres, the warnings. The reports of how the bone was recognised
(``recognition``) and how the markers were paired (``pairing``) are not kept; a CT with a marker not found
(``missing``) is not cached, so its report is always made whole. The segmentation's denoised copy of the CT
(``smoothed``, float32, twice the CT's size) is only needed while processing and is not kept: it is None in every
result of ``cached_image_side``, read or made.
"""

import hashlib
import logging
import time
from dataclasses import fields, replace
from pathlib import Path

import numpy as np

from ..image.ct_pipeline import ImageSideResult, process_ct
from ..image.ct_segmentation import DEFAULT_THRESHOLD_HU, BoneSegmentation, BoneSurface
from ..image.marker_spheres import MarkerSphere
from ..image.metal import MetalZone
from ..io.npz_cache import read_npz, write_npz
from ..simulation.phantom_cache import library_sources

logger = logging.getLogger(__name__)

#: Raise when the result's meaning or this file's layout changes without a change to the image package's source.
IMAGE_SIDE_VERSION = 2
_SPHERE_FIELDS = tuple(field.name for field in fields(MarkerSphere))
_METAL_FIELDS = tuple(field.name for field in fields(MetalZone))


def image_side_key(volume, threshold_hu, fill_cavities, tool_markers):
    """Hex SHA-256 of everything ``process_ct(volume, ...)`` depends on (see the module's docstring)."""
    digest = hashlib.sha256(f"ramsicp image side v{IMAGE_SIDE_VERSION}".encode())
    for name, source in library_sources():
        digest.update(name.encode())
        digest.update(source)
    markers = None if tool_markers is None else np.asarray(tool_markers, dtype=np.float64)
    for array in (volume.voxels, volume.ijk_to_ras, markers):
        if array is None:
            digest.update(b"none")
            continue
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(memoryview(array).cast("B"))
    digest.update(repr((str(threshold_hu), bool(fill_cavities))).encode())
    return digest.hexdigest()


def cached_image_side(
    volume, threshold_hu=DEFAULT_THRESHOLD_HU, fill_cavities=True, tool_markers=None, progress=None, directory=None
):
    """``process_ct(volume, threshold_hu, fill_cavities, tool_markers, progress)``, read from the cache when this CT
    was processed so before, else processed and written to it (``directory``, default ``cache_directory()``).
    ``result.seconds`` has ``"cache_read"`` when it was read."""
    from ..simulation.phantom_cache import cache_directory

    clock = time.perf_counter()
    key = image_side_key(volume, threshold_hu, fill_cavities, tool_markers)
    path = (cache_directory() if directory is None else Path(directory)) / f"image-side-{key[:32]}.npz"
    result = _read(path, volume.voxels.shape)
    if result is not None:
        if progress is not None:
            progress("marker spheres", 3, 3)
        return replace(result, seconds={"cache_read": time.perf_counter() - clock})
    result = process_ct(volume, threshold_hu, fill_cavities, tool_markers, progress)
    result = replace(result, segmentation=replace(result.segmentation, smoothed=None))  # the same whether read or not
    if result.missing:
        return result  # where the missing marker is expected is reported from a whole processing, every time
    write_npz(path, _arrays(result), logger, "processed CT", "it will be processed again")
    return result


def _arrays(result):
    """The result as named arrays (plain types only: read back without pickle)."""
    segmentation, surface, spheres = result.segmentation, result.surface, result.spheres
    labels = segmentation.labels
    where = np.flatnonzero(labels)
    arrays = {
        "threshold_hu": np.float64(segmentation.threshold_hu),
        "label_shape": np.array(labels.shape, dtype=np.int64),
        "box": np.array([[-1, -1]] * 3 if segmentation.box is None else [[b.start, b.stop] for b in segmentation.box]),
        "volume_shape": np.array(segmentation.volume_shape or (-1, -1, -1), dtype=np.int64),
        "body_index": np.flatnonzero(segmentation.body).astype(np.int64)
        if segmentation.body is not None
        else np.zeros(0, dtype=np.int64),
        "has_body": np.bool_(segmentation.body is not None),
        "body_margin_mm": np.float64(segmentation.body_margin_mm),
        "surface_left_out_body": np.int64(surface.left_out_body),
        "label_dtype": np.array(labels.dtype.str),
        "label_index": where.astype(np.int64),
        "label_value": labels.ravel()[where],
        "bone_label": np.int64(segmentation.bone_label),
        "object_labels": np.array(segmentation.object_labels, dtype=np.int64),
        "surface_points": surface.points,
        "surface_triangles": surface.triangles,
        "surface_left_out": np.int64(surface.left_out),
        "surface_left_out_base": np.int64(surface.left_out_base),
        "has_metal": np.bool_(surface.metal is not None),
        "warnings": np.array(result.warnings, dtype=str).reshape(-1),
    }
    if surface.metal is not None:
        for name in _METAL_FIELDS:
            value = getattr(surface.metal, name)
            arrays[f"metal_{name}"] = np.array(np.nan if value is None else value)  # only the centre may be None
    for name in _SPHERE_FIELDS:
        column = [getattr(sphere, name) for sphere in spheres]
        arrays[f"sphere_{name}"] = np.array(column).reshape(len(spheres), -1) if spheres else np.zeros((0, 1))
    return arrays


def _read(path, shape):
    """The ImageSideResult in ``path``, or None when there is none or it is damaged (then it is made again)."""
    return read_npz(path, lambda stored: _result(stored, shape), logger, "processed CT", "processing the CT again")


def _result(stored, shape):
    bounds = stored["box"]
    box = None if bounds[0][0] < 0 else tuple(slice(int(start), int(stop)) for start, stop in bounds)
    label_shape = tuple(int(size) for size in stored["label_shape"])
    expected = tuple(shape) if box is None else tuple(s.stop - s.start for s in box)
    if label_shape != expected or (box is not None and tuple(stored["volume_shape"]) != tuple(shape)):
        raise ValueError(f"its labels are {label_shape} voxels, the CT's box {expected}")
    if box is not None and any(s.start < 0 or s.stop > size for s, size in zip(box, shape)):
        raise ValueError("its box lies outside the CT")
    labels = np.zeros(label_shape, dtype=np.dtype(str(stored["label_dtype"])))
    labels.ravel()[stored["label_index"]] = stored["label_value"]  # IndexError when the indices are out of range
    body = None
    if bool(stored["has_body"]):
        body = np.zeros(label_shape, dtype=bool)
        body.ravel()[stored["body_index"]] = True
    segmentation = BoneSegmentation(
        smoothed=None,
        threshold_hu=float(stored["threshold_hu"]),
        labels=labels,
        bone_label=int(stored["bone_label"]),
        object_labels=tuple(int(label) for label in stored["object_labels"]),
        box=box,
        volume_shape=None if box is None else tuple(shape),
        body=body,
        body_margin_mm=float(stored["body_margin_mm"]),
    )
    points, triangles = stored["surface_points"], stored["surface_triangles"]
    if points.ndim != 2 or points.shape[1] != 3 or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise ValueError("its IPC is not (M, 3) points and (K, 3) triangles")
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(points)):
        raise ValueError("its IPC's triangles name points it does not have")
    metal = None
    if bool(stored["has_metal"]):
        values = {name: stored[f"metal_{name}"] for name in _METAL_FIELDS}
        values["metal_mm3"], values["margin_mm"] = float(values["metal_mm3"]), float(values["margin_mm"])
        values["reach_mm"] = float(values["reach_mm"])
        values["centre"] = None if values["centre"].ndim == 0 else values["centre"]
        metal = MetalZone(**values)
    left_out, left_out_body = int(stored["surface_left_out"]), int(stored["surface_left_out_body"])
    surface = BoneSurface(points, triangles, metal, left_out, left_out_body, int(stored["surface_left_out_base"]))
    columns = {name: stored[f"sphere_{name}"] for name in _SPHERE_FIELDS}
    spheres = tuple(
        MarkerSphere(**{name: _sphere_value(name, column[row]) for name, column in columns.items()})
        for row in range(len(columns["centre"]))
    )
    return ImageSideResult(segmentation, surface, spheres, tuple(str(text) for text in stored["warnings"]))


def _sphere_value(name, row):
    """A MarkerSphere field from its row in the stored column: the centre (3,) mm, the others plain values."""
    if name == "centre":
        if row.shape != (3,):
            raise ValueError("a sphere centre is not 3 numbers")
        return row.astype(np.float64)
    return row[0].item()
