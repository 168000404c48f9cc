"""Reading rerun recordings back into numpy: what ``Recorder`` wrote, for tests and scripts."""

from __future__ import annotations

import numpy as np

from ..errors import WarpShapeError, check_input_file

__all__ = ["read_recording", "check_recording_file"]

#: the first bytes of every rerun recording file (``RRF`` and a format version digit)
RRD_MAGIC = b"RRF"


def check_recording_file(path) -> None:
    """A clear ``WarpShapeError`` unless ``path`` is a regular file that starts as a rerun recording does."""
    try:
        check_input_file(path, "recording", WarpShapeError)
    except WarpShapeError as exc:
        if "not found" not in str(exc):
            raise
        raise WarpShapeError(f"no recording at {path}; write one with --rerun FILE.rrd (e.g. warp-shape design "
                             f"--rerun out/design.rrd)") from None
    with open(path, "rb") as f:
        head = f.read(len(RRD_MAGIC))
    if head != RRD_MAGIC:
        raise WarpShapeError(f"{path} is not a rerun recording (a .rrd starts with {RRD_MAGIC.decode()!r}, this "
                             f"file with {head!r}); give the .rrd a run wrote with --rerun FILE.rrd")


def read_recording(path) -> dict:
    """Read a ``.rrd`` written by ``Recorder`` back into numpy (for tests and scripts).

    Returns ``{"entities": {path: {"static": {component: value}, "times": {timeline: (N,) array},
    component: [value per row]}}, "blueprint": [view class identifiers], "blueprint_views":
    [(class, display name, origin)]}``. Temporal rows are ordered by ``control_step``, ``sim_step``
    or ``round`` (whichever the entity has); ``sim_time`` comes back in seconds; ``log_time`` is
    left out. Component names are rerun's column names, e.g. ``Mesh3D:vertex_positions``,
    ``Scalars:scalars``; list values come back as numpy arrays.
    """
    import pyarrow as pa
    import rerun as rr

    check_recording_file(path)
    reader = rr.chunk.RrdReader(str(path))
    entities: dict = {}
    for ch in reader.stream():
        rb = ch.to_record_batch()
        ent = entities.setdefault(ch.entity_path, {"static": {}, "times": {}, "_rows": []})
        names = [n for n in rb.schema.names if n not in ("rerun.controls.RowId", "log_time")]
        timelines = [n for n in names if n in ch.timeline_names]
        comps = [n for n in names if n not in timelines]
        values = {n: [np.asarray(v) if isinstance(v, list) else v for v in rb.column(n).to_pylist()] for n in comps}
        if ch.is_static:
            for n in comps:
                ent["static"][n] = values[n][-1]
            continue
        times = {}
        for n in timelines:
            col = rb.column(n)
            if pa.types.is_duration(col.type):
                times[n] = col.cast(pa.int64()).to_numpy(zero_copy_only=False) * 1e-9
            else:
                times[n] = col.cast(pa.int64()).to_numpy(zero_copy_only=False)
        for r in range(rb.num_rows):
            ent["_rows"].append(({k: v[r] for k, v in times.items()}, {n: values[n][r] for n in comps}))
    for ent in entities.values():
        rows = ent.pop("_rows")
        key = next((k for k in ("control_step", "sim_step", "round") if rows and k in rows[0][0]), None)
        if key is not None:
            rows.sort(key=lambda r: r[0][key])
        for t, c in rows:
            for k, v in t.items():
                ent["times"].setdefault(k, []).append(v)
            for k, v in c.items():
                ent.setdefault(k, []).append(v)
        ent["times"] = {k: np.asarray(v) for k, v in ent["times"].items()}
    views = []
    if reader.blueprints():
        for ch in reader.stream(store=reader.blueprints()[-1]):
            rb = ch.to_record_batch()
            if "ViewBlueprint:class_identifier" in rb.schema.names:
                get = lambda n: (rb.column(n).to_pylist()[-1] or [None])[0] if n in rb.schema.names else None  # noqa: E731
                views.append((get("ViewBlueprint:class_identifier"), get("ViewBlueprint:display_name"),
                              get("ViewBlueprint:space_origin")))
    return dict(entities=entities, blueprint=sorted({v[0] for v in views}), blueprint_views=views)
