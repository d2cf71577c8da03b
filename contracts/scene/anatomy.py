"""The phantom's anatomy in numbers: clearances between its shapes, the checks that keep a variant valid,
and the figures a comparison of variants reports (prostate length, rectal-wall thickness, offset).

Shapes (phantom.py; mm, x lateral, y posterior -> anterior, z up): prostate an ellipsoid, bladder a
sphere, rectal wall a tube along z through the whole block (the lumen its inner cylinder), pubic bone
a bar along x, spine a box. Where two shapes overlap, phantom.PRIORITY gives the overlap to one of
them, and the default phantom uses that on purpose: its prostate presses 1 mm into the rectal wall,
and its bladder touches the wall. A phantom is refused (`problems`) when

- a shape leaves the block (it would be cut at the block's face);
- the rectal wall, or what is left of it between the lumen and a tissue pressing into it, is thinner
  than MIN_WALL_MM: the guide pushes on the lumen's wall, and a label map must keep a voxel of it;
- the prostate overlaps the bladder, or a bone overlaps a soft tissue (PRIORITY would cut the
  lower-priority tissue's shape);
- the guide tip is not on the lumen surface, or its axis does not push into the wall.

Clearance between two shapes: the smallest signed distance from one's surface to the other (exact
for every pair but the prostate's, whose ellipsoid surface is sampled, SURFACE_STEPS); negative is
an overlap that deep.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from contracts.scene import Guide, Phantom

# The wall between the lumen and any tissue: one voxel of the coarsest label map the fixtures use (1 mm).
MIN_WALL_MM = 1.0
TIP_TOL_MM = 0.01  # the phantom's tip is exact: it must lie on the lumen cylinder to this
# Polar x azimuthal samples of the prostate's surface, 0.8 mm apart on a 30 mm semi-axis: a sampled
# clearance is within 0.01 mm of one sampled 16 times finer (tests/contracts/scene/test_anatomy.py).
SURFACE_STEPS = (121, 240)


def ellipsoid_surface(centre, semi_axes, steps: tuple[int, int] = SURFACE_STEPS) -> np.ndarray:
    """Points (k, 3) on an ellipsoid's surface, on a polar x azimuthal grid."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, steps[0]), np.linspace(0, 2 * np.pi, steps[1], endpoint=False),
                             indexing="ij")
    unit = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    return np.asarray(centre) + unit.reshape(-1, 3) * np.asarray(semi_axes)


def sd_z_cylinder(points: np.ndarray, centre_xy, radius: float) -> np.ndarray:
    """Signed distance (k,) to an infinite cylinder along z."""
    return np.linalg.norm(points[:, :2] - np.asarray(centre_xy), axis=1) - radius


def sd_sphere(points: np.ndarray, centre, radius: float) -> np.ndarray:
    """Signed distance (k,) to a sphere."""
    return np.linalg.norm(points - np.asarray(centre), axis=1) - radius


def sd_box(points: np.ndarray, lo, hi) -> np.ndarray:
    """Signed distance (k,) to the axis-aligned box [lo, hi] (any dimension)."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    q = np.abs(points - 0.5 * (lo + hi)) - 0.5 * (hi - lo)
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def sd_x_bar(points: np.ndarray, centre, radius: float, length: float) -> np.ndarray:
    """Signed distance (k,) to a capped cylinder along x (the pubic bone)."""
    c = np.asarray(centre)
    d = np.stack([np.linalg.norm(points[:, 1:] - c[1:], axis=1) - radius, np.abs(points[:, 0] - c[0]) - length / 2],
                 axis=1)
    return np.linalg.norm(np.maximum(d, 0), axis=1) + np.minimum(d.max(axis=1), 0)


def _inside_ellipsoid(point, centre, semi_axes) -> bool:
    return float(np.sum(((np.asarray(point) - centre) / np.asarray(semi_axes)) ** 2)) < 1.0


def clearances_mm(ph: Phantom) -> dict[str, float]:
    """Signed clearance (mm) of each pair of shapes whose overlap matters: negative is the overlap's depth,
    -inf one shape inside the other. `prostate-lumen` and `bladder-lumen` are the tissue left between the
    lumen and that organ. The two bones are not paired: both are held fixed, so their overlap changes nothing.
    """
    prostate = ellipsoid_surface(ph.prostate_center_mm, ph.prostate_semi_axes_mm)  # (k, 3)
    rc, r_in, r_out = ph.rectum_center_xy_mm, ph.rectum_inner_radius_mm, ph.rectum_outer_radius_mm
    bc, br = np.asarray(ph.bladder_center_mm)[None], ph.bladder_radius_mm
    spine_lo, spine_hi = np.asarray(ph.spine_box_mm)
    pubic = dict(centre=ph.pubic_center_mm, radius=ph.pubic_radius_mm, length=ph.pubic_length_mm)
    px, py, _ = ph.pubic_center_mm
    # The tube spans the block's height, so against it only the other shape's xy footprint counts.
    half = np.array([ph.pubic_length_mm / 2, ph.pubic_radius_mm])
    pubic_xy = (np.array([px, py]) - half, np.array([px, py]) + half)
    rc_point = np.asarray(rc, dtype=float)[None]
    out = {
        "prostate-lumen": sd_z_cylinder(prostate, rc, r_in).min(),
        "prostate-bladder": sd_sphere(prostate, bc[0], br).min(),
        "prostate-pubic_bone": sd_x_bar(prostate, **pubic).min(),
        "prostate-spine": sd_box(prostate, spine_lo, spine_hi).min(),
        "bladder-lumen": sd_z_cylinder(bc, rc, r_in)[0] - br,
        "bladder-pubic_bone": sd_x_bar(bc, **pubic)[0] - br,
        "bladder-spine": sd_box(bc, spine_lo, spine_hi)[0] - br,
        "rectal_wall-pubic_bone": sd_box(rc_point, *pubic_xy)[0] - r_out,
        "rectal_wall-spine": sd_box(rc_point, spine_lo[:2], spine_hi[:2])[0] - r_out,
    }
    # A shape wholly inside the prostate leaves its surface untouched: the sampled clearance cannot see it.
    inner = {"prostate-bladder": ph.bladder_center_mm, "prostate-pubic_bone": ph.pubic_center_mm,
             "prostate-spine": 0.5 * (spine_lo + spine_hi), "prostate-lumen": (*rc, ph.prostate_center_mm[2])}
    for pair, point in inner.items():
        if _inside_ellipsoid(point, ph.prostate_center_mm, ph.prostate_semi_axes_mm):
            out[pair] = -np.inf
    return {k: float(v) for k, v in out.items()}


def block_margins_mm(ph: Phantom) -> dict[str, float]:
    """How far each shape stays inside the block (mm; negative: it sticks out), in x, y and z (the tube: x, y)."""
    bx, by, bz = ph.block_mm
    block_lo, block_hi = np.array([-bx / 2, -by / 2, 0.0]), np.array([bx / 2, by / 2, bz])
    px, py, pz = ph.pubic_center_mm
    pr, pl = ph.pubic_radius_mm, ph.pubic_length_mm / 2
    pc, pa = np.asarray(ph.prostate_center_mm), np.asarray(ph.prostate_semi_axes_mm)
    bc, br = np.asarray(ph.bladder_center_mm), ph.bladder_radius_mm
    boxes = {  # (lo, hi) of each shape's bounding box, which touches the shape on every face
        "prostate": (pc - pa, pc + pa),
        "bladder": (bc - br, bc + br),
        "rectal_wall": (np.array([*np.subtract(ph.rectum_center_xy_mm, ph.rectum_outer_radius_mm), 0.0]),
                        np.array([*np.add(ph.rectum_center_xy_mm, ph.rectum_outer_radius_mm), bz])),
        "pubic_bone": (np.array([px - pl, py - pr, pz - pr]), np.array([px + pl, py + pr, pz + pr])),
        "spine": tuple(np.asarray(ph.spine_box_mm)),
    }
    return {name: float(min((lo - block_lo).min(), (block_hi - hi).min())) for name, (lo, hi) in boxes.items()}


def problems(ph: Phantom) -> list[str]:
    """What makes a phantom unusable, one sentence each naming the fields (empty: valid)."""
    found = [f"the {name} leaves the block by {-m:.2f} mm (block_mm and the {name}'s fields)"
             for name, m in block_margins_mm(ph).items() if m < 0]
    wall = ph.rectum_outer_radius_mm - ph.rectum_inner_radius_mm
    if wall < MIN_WALL_MM:
        found.append(f"the rectal wall is {wall:.2f} mm thick, less than {MIN_WALL_MM} mm "
                     "(rectum_outer_radius_mm - rectum_inner_radius_mm)")
    fields = {"prostate": "prostate_center_mm, prostate_semi_axes_mm",
              "bladder": "bladder_center_mm, bladder_radius_mm",
              "pubic_bone": "pubic_center_mm, pubic_radius_mm, pubic_length_mm", "spine": "spine_box_mm",
              "lumen": "rectum_center_xy_mm, rectum_inner_radius_mm",
              "rectal_wall": "rectum_center_xy_mm, rectum_outer_radius_mm"}
    for pair, c in clearances_mm(ph).items():
        a, b = pair.split("-")
        where = f"({fields[a]}; {fields[b]})"
        if b == "lumen" and c < 0:
            depth = "surrounds the lumen" if c == -np.inf else f"reaches {-c:.2f} mm into the lumen"
            found.append(f"the {a} {depth}; at least {MIN_WALL_MM} mm of rectal wall must separate them {where}")
        elif b == "lumen" and c < MIN_WALL_MM:
            found.append(f"the {a} leaves {c:.2f} mm of rectal wall at the lumen, less than {MIN_WALL_MM} mm {where}")
        elif b != "lumen" and c == -np.inf:
            found.append(f"the {b} lies inside the {a} {where}")
        elif b != "lumen" and c < -1e-9:  # touching is allowed: the interface is bonded either way
            found.append(f"the {a} and the {b} overlap by {-c:.2f} mm {where}")
    return found


def tip_problem(ph: Phantom, guide: Guide) -> str | None:
    """Why the guide tip is not on the phantom's lumen surface pushing into the wall, or None."""
    rc, r_in = np.asarray(ph.rectum_center_xy_mm), ph.rectum_inner_radius_mm
    tip = np.asarray(guide.tip_mm)
    radial = tip[:2] - rc
    r = float(np.linalg.norm(radial))
    if abs(r - r_in) > TIP_TOL_MM or not 0 < tip[2] < ph.block_mm[2]:
        normal = radial / r if r > 0 else np.array([0.0, 1.0])
        on = np.round(np.append(rc + r_in * normal, np.clip(tip[2], 0, ph.block_mm[2])), 3).tolist()
        return (f"guide.tip_mm: {list(guide.tip_mm)} is {abs(r - r_in):.2f} mm off the phantom's lumen surface "
                f"(radius rectum_inner_radius_mm = {r_in} about rectum_center_xy_mm = {list(rc)}, 0 < z < "
                f"{ph.block_mm[2]}); the nearest point on it is {on}")
    axis = np.asarray(guide.axis, dtype=float)
    if axis[:2] @ radial <= 0:
        return (f"guide.axis: {list(guide.axis)} does not push the tip at {list(guide.tip_mm)} into the rectal wall "
                "(outward from the lumen)")
    return None


def describe(ph: Phantom) -> dict:
    """The figures that tell variants apart: prostate size and offset, rectal wall,
    the tissue between lumen and prostate."""
    a = np.asarray(ph.prostate_semi_axes_mm)
    gaps = clearances_mm(ph)
    default_centre = type(ph).model_fields["prostate_center_mm"].default
    return {
        "prostate_length_mm": float(2 * a[0]),
        "prostate_size_mm": (2 * a).tolist(),  # x, y, z extents
        "prostate_volume_ml": float(4 / 3 * np.pi * a.prod() / 1000),
        "prostate_center_mm": list(ph.prostate_center_mm),
        "prostate_offset_mm": np.subtract(ph.prostate_center_mm, default_centre).tolist(),  # from the default phantom's
        "rectal_wall_mm": ph.rectum_outer_radius_mm - ph.rectum_inner_radius_mm,
        "prostate_to_lumen_mm": gaps["prostate-lumen"],  # the wall (and any fat) the guide pushes through
        "clearances_mm": gaps,
    }
