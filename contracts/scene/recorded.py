"""What a scene recorded before a field existed means by its absence.

A sweep's and a model's manifest hold the whole validated scene as JSON (contracts.sweep, contracts.model). A field
added to the schema later is missing from the manifests written before it, and its default today need not be what
those scenes meant (the glued patch before `effects.guide_contact`, the pointwise element before
`solver.volumetric`). `LATER_FIELDS` holds, for each, the value that reproduces what a scene meant before it existed:

- a manifest's scene reads a later field it lacks at that value (`fill`), not at today's default;
- written back, it leaves out again each field it lacked while that field still holds the value (`drop`), so a
  manifest read and written is the same bytes;
- a scene's hash leaves out every later field at that value (schema.Scene.sha256), so the scenes, sweeps and models
  made before the field keep their hashes (also after its default changed).
"""

from __future__ import annotations

from collections.abc import Iterable

Field = tuple[str | None, str]  # (section, field); section None: a field of the scene itself

# (section, field) -> the value that reproduces what the scene meant before the field existed
LATER_FIELDS: dict[Field, object] = {
    (None, "label_map"): None, ("guide", "snap_mm"): None, ("guide", "snap_to"): "node",
    ("guide", "tip_radius_mm"): 6.0, ("guide", "contact_stiffness_kpa_mm"): 3e4,
    ("guide", "contact_stiffness_per_mm"): None, ("guide", "contact_tol_mm"): 0.005,
    ("effects", "guide_contact"): False, ("label_map", "facet_distance_voxels"): 0.5,
    ("solver", "volumetric"): "pointwise", ("mesh", "surface_near_tip_mm"): None,
    (None, "materials"): None}


def fill(data: dict) -> tuple[dict, frozenset[Field]]:
    """A copy of a scene's JSON with each later field it lacks at its value from before, and the fields it lacked.
    A section the scene does not have (an optional one, label_map) gets none."""
    out = dict(data)
    absent = set()
    for (section, key), before in LATER_FIELDS.items():
        if section is not None and not isinstance(out.get(section), dict):
            continue
        if section is not None and out[section] is data.get(section):
            out[section] = dict(out[section])  # copied once, before the first field goes in
        parent = out if section is None else out[section]
        if key not in parent:
            parent[key] = before
            absent.add((section, key))
    return out, frozenset(absent)


def drop(data: dict, fields: Iterable[Field]) -> dict:
    """`data` (a scene's dump) without each of `fields` that holds its value from before; changed in place."""
    for section, key in fields:
        parent = data if section is None else data.get(section)
        if isinstance(parent, dict) and key in parent and parent[key] == LATER_FIELDS[section, key]:
            parent.pop(key)
    return data
