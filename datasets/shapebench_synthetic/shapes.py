"""Procedural ShapeNet-like shape families for the synthetic dataset.

Each family draws dimensions, proportions and part counts from a numpy ``Generator`` and
assembles the object from simple solids (boxes, prisms, cylinders, spheres, convex hulls and
surfaces of revolution). Parts are made to overlap slightly and are merged with a real boolean
union in manifold3d, so every mesh is one watertight, outward-oriented solid with no internal
faces hidden inside other parts. Hollow objects (mug, bowl, lamp shade) are carved with boolean
differences so their walls have real thickness.

Frame: families are authored **z-up** with the object's front toward -y, because manifold3d
builds cylinders, extrusions and revolutions along +z. ``Family.build`` and :func:`generate`
rotate the result to **y-up** (ShapeNet's convention; the front then faces +z). Units are
arbitrary (roughly metres): a later stage recentres and rescales.

Bump :data:`GENERATOR_VERSION` whenever any family's geometry changes, so cached datasets built
from an older version are not silently mixed with new shapes.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
import trimesh
from manifold3d import CrossSection, Manifold, OpType

__all__ = [
    "CATEGORIES",
    "GENERATOR_VERSION",
    "Family",
    "UnknownCategoryError",
    "generate",
    "novel_categories",
    "trained_categories",
]

GENERATOR_VERSION = "1"

SEGMENTS = 48  # circle resolution of prominent round parts (table tops, bottles, bowls)
SMALL_SEGMENTS = 16  # legs, poles, knobs: small enough that facets are invisible
SPHERE_SEGMENTS = 16  # geodesic spheres used for hulls and joints

Point = Sequence[float]
Solid = Manifold
SolidBuilder = Callable[[np.random.Generator], Solid]  # a family, authored z-up


# --------------------------------------------------------------------------------------------
# Random draws: tiny wrappers so families read like specs and always return Python scalars.
# --------------------------------------------------------------------------------------------


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    """Uniform float in [lo, hi)."""
    return float(rng.uniform(lo, hi))


def _i(rng: np.random.Generator, lo: int, hi: int) -> int:
    """Uniform integer in [lo, hi] (inclusive, unlike ``Generator.integers``)."""
    return int(rng.integers(lo, hi + 1))


def _chance(rng: np.random.Generator, p: float) -> bool:
    """True with probability ``p``."""
    return bool(rng.random() < p)


def _pick(rng: np.random.Generator, options: Sequence[str], weights: Sequence[float] = ()) -> str:
    """One of ``options`` (optionally weighted); avoids numpy string scalars leaking out."""
    p = None
    if weights:
        w = np.asarray(weights, dtype=float)
        p = w / w.sum()
    return options[int(rng.choice(len(options), p=p))]


# --------------------------------------------------------------------------------------------
# Primitive solids shared by all families.
# --------------------------------------------------------------------------------------------


def _vec(p: Point) -> np.ndarray:
    return np.asarray(p, dtype=float)


def _tuple(p: Point) -> tuple[float, float, float]:
    x, y, z = (float(c) for c in p)
    return (x, y, z)


def box(size: Point, center: Point = (0.0, 0.0, 0.0)) -> Solid:
    """Axis-aligned box from size and centre: boards, panels, bodies."""
    return Manifold.cube(_tuple(size), center=True).translate(_tuple(center))


def box_span(lo: Point, hi: Point) -> Solid:
    """Axis-aligned box between two corners; overlaps are easier to reason about this way."""
    a, b = _vec(lo), _vec(hi)
    return box(b - a, (a + b) / 2)


def _basis(direction: Point) -> np.ndarray:
    """Rotation matrix whose third column is the unit ``direction`` (local +z maps onto it)."""
    d = _vec(direction)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, d)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    return np.column_stack([u, v, d])


def place(part: Solid, origin: Point, direction: Point) -> Solid:
    """Move a part authored from the origin along +z to start at ``origin`` along ``direction``."""
    return part.transform(np.column_stack([_basis(direction), _vec(origin)]))


def cylinder_between(
    p: Point, q: Point, r: float, segments: int = SMALL_SEGMENTS, r_end: float | None = None
) -> Solid:
    """Cylinder (or frustum when ``r_end`` is given) from point ``p`` to point ``q``."""
    a, b = _vec(p), _vec(q)
    length = float(np.linalg.norm(b - a))
    part = Manifold.cylinder(length, r, r if r_end is None else r_end, segments)
    return place(part, a, b - a)


def sphere(center: Point, r: float, segments: int = SPHERE_SEGMENTS) -> Solid:
    return Manifold.sphere(r, segments).translate(_tuple(center))


def hull(points: Iterable[Point]) -> Solid:
    """Convex hull of points: wings, tapered bodies, slanted panels."""
    return Manifold.hull_points(np.asarray(list(points), dtype=float))


def capsule(p: Point, q: Point, r: float, r_end: float | None = None) -> Solid:
    """Rounded rod (hull of two spheres); tapered when ``r_end`` differs from ``r``."""
    return Manifold.batch_hull([sphere(p, r), sphere(q, r if r_end is None else r_end)])


def prism_between(
    p: Point,
    q: Point,
    half_x: float,
    half_y: float,
    half_x_end: float | None = None,
    half_y_end: float | None = None,
) -> Solid:
    """Hull of two horizontal axis-aligned rectangles centred at ``p`` and ``q``.

    Used for square legs (with splay and taper), tilted backrests and posts, which a plain box
    cannot express without rotations that would misalign the rectangle edges.
    """
    hx1 = half_x if half_x_end is None else half_x_end
    hy1 = half_y if half_y_end is None else half_y_end
    corners = [
        (c[0] + sx * hx, c[1] + sy * hy, c[2])
        for c, hx, hy in ((p, half_x, half_y), (q, hx1, hy1))
        for sx in (-1.0, 1.0)
        for sy in (-1.0, 1.0)
    ]
    return hull(corners)


def rounded_box(lo: Point, hi: Point, radius: float) -> Solid:
    """Box with rounded edges (hull of corner spheres): cushions, mattresses, pillows."""
    a, b = _vec(lo), _vec(hi)
    r = min(radius, 0.45 * float(np.min(b - a)))
    spheres = [
        sphere((x, y, z), r, 8)
        for x in (a[0] + r, b[0] - r)
        for y in (a[1] + r, b[1] - r)
        for z in (a[2] + r, b[2] - r)
    ]
    return Manifold.batch_hull(spheres)


def revolve(
    profile: Sequence[tuple[float, float]], segments: int = SEGMENTS, degrees: float = 360.0
) -> Solid:
    """Solid of revolution about +z from an (r, z) outline: bottles, bowls, tori."""
    pts = np.asarray(profile, dtype=float)
    signed_area = 0.5 * float(
        np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    )
    if signed_area < 0:  # CrossSection's positive fill rule wants counter-clockwise outlines
        pts = pts[::-1]
    return CrossSection([pts]).revolve(segments, degrees)


def torus(major: float, minor: float, segments: int = SEGMENTS, degrees: float = 360.0) -> Solid:
    """Torus (or a bent pipe when ``degrees`` < 360) around +z, starting on the +x axis."""
    ring = CrossSection.circle(minor, SMALL_SEGMENTS).translate((major, 0.0))
    return ring.revolve(segments, degrees)


def union(parts: Iterable[Solid]) -> Solid:
    """Real boolean union: overlapping parts become one solid with no internal faces."""
    return Manifold.batch_boolean(list(parts), OpType.Add)


def difference(base: Solid, cuts: Iterable[Solid]) -> Solid:
    """``base`` minus every cut: hollows, recesses, wheel arches."""
    return Manifold.batch_boolean([base, *cuts], OpType.Subtract)


def mirror_x(parts: Iterable[Solid]) -> list[Solid]:
    """Parts plus their mirror images across the x = 0 plane (left/right symmetry)."""
    parts = list(parts)
    return parts + [p.mirror((1.0, 0.0, 0.0)) for p in parts]


def rect_corners(half_x: float, half_y: float) -> list[tuple[float, float]]:
    """The four (x, y) corners of a centred rectangle, e.g. leg positions."""
    return [(sx * half_x, sy * half_y) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]


# --------------------------------------------------------------------------------------------
# Legs: shared by chair, table, bench, bed, sofa, cabinet.
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LegStyle:
    """How a set of legs looks; drawn once per object so all legs match."""

    radius: float  # half-width at the top
    square: bool
    taper: float  # foot size / top size
    splay: float  # outward horizontal offset of each foot


def draw_leg_style(
    rng: np.random.Generator, r_lo: float, r_hi: float, max_splay: float = 0.04
) -> LegStyle:
    return LegStyle(
        radius=_u(rng, r_lo, r_hi),
        square=_chance(rng, 0.5),
        taper=_u(rng, 0.55, 1.0),
        splay=_u(rng, 0.0, max_splay) if _chance(rng, 0.5) else 0.0,
    )


def _foot_xy(style: LegStyle, x: float, y: float) -> tuple[float, float]:
    """Foot position: the top position pushed outward from the centre by the splay."""
    n = math.hypot(x, y)
    if n == 0.0 or style.splay == 0.0:
        return x, y
    return x + style.splay * x / n, y + style.splay * y / n


def leg_point(
    style: LegStyle, x: float, y: float, z_bottom: float, z_top: float, z: float
) -> tuple[float, float, float]:
    """Point on the axis of the leg under (x, y) at height z, for stretchers and shelves."""
    fx, fy = _foot_xy(style, x, y)
    t = (z - z_bottom) / (z_top - z_bottom)
    return (fx + (x - fx) * t, fy + (y - fy) * t, z)


def leg(style: LegStyle, x: float, y: float, z_bottom: float, z_top: float) -> Solid:
    fx, fy = _foot_xy(style, x, y)
    r, rb = style.radius, style.radius * style.taper
    if style.square:
        return prism_between((fx, fy, z_bottom), (x, y, z_top), rb, rb, r, r)
    return cylinder_between((fx, fy, z_bottom), (x, y, z_top), rb, SMALL_SEGMENTS, r_end=r)


def leg_set(
    style: LegStyle, xy: Iterable[tuple[float, float]], z_bottom: float, z_top: float
) -> list[Solid]:
    return [leg(style, x, y, z_bottom, z_top) for x, y in xy]


def stretchers(
    style: LegStyle,
    xy: Sequence[tuple[float, float]],
    z_bottom: float,
    z_top: float,
    z: float,
    pairs: Sequence[tuple[int, int]],
) -> list[Solid]:
    """Horizontal rods between leg axes (ends sit on the axes, so they overlap the legs)."""
    r = 0.55 * style.radius
    pts = [leg_point(style, x, y, z_bottom, z_top, z) for x, y in xy]
    return [cylinder_between(pts[a], pts[b], r) for a, b in pairs]


def rail_between(
    a: tuple[float, float], b: tuple[float, float], thickness: float, z0: float, z1: float
) -> Solid:
    """Board between two (x, y) points on an axis-aligned edge: aprons, rails."""
    lo = (min(a[0], b[0]) - thickness / 2, min(a[1], b[1]) - thickness / 2, z0)
    hi = (max(a[0], b[0]) + thickness / 2, max(a[1], b[1]) + thickness / 2, z1)
    return box_span(lo, hi)


# Indices into rect_corners(): 0=(-,-) 1=(-,+) 2=(+,-) 3=(+,+).
SIDE_PAIRS = ((0, 1), (2, 3))
ALL_EDGE_PAIRS = ((0, 1), (2, 3), (0, 2), (1, 3))


# --------------------------------------------------------------------------------------------
# Registry.
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Family:
    """One category: a named, seeded generator of shapes of the same kind."""

    name: str
    split: str  # "trained" or "novel"
    description: str
    build: Callable[[np.random.Generator], trimesh.Trimesh]


CATEGORIES: dict[str, Family] = {}


class UnknownCategoryError(ValueError, KeyError):
    """Unknown category name; a ValueError that ``except KeyError`` also catches."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


def _drop_slivers(solid: Solid) -> Solid:
    """Remove zero-volume components, a numerical by-product of exactly touching faces.

    Real (positive-volume) pieces are kept, so a genuinely disconnected part still shows up.
    """
    pieces = solid.decompose()
    if len(pieces) <= 1:
        return solid
    total = sum(p.volume() for p in pieces)
    return Manifold.compose([p for p in pieces if p.volume() > 1e-9 * total])


def _to_trimesh(solid: Solid) -> trimesh.Trimesh:
    """Convert a z-up manifold to a y-up trimesh (proper rotation, so winding stays outward)."""
    if solid.is_empty():
        raise RuntimeError(f"shape generator produced an empty solid ({solid.status()})")
    solid = _drop_slivers(solid)
    mesh = solid.to_mesh64()
    v = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    y_up = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]])
    return trimesh.Trimesh(vertices=y_up, faces=faces, process=True)


def _build(fn: SolidBuilder, rng: np.random.Generator) -> trimesh.Trimesh:
    return _to_trimesh(fn(rng))


def _family(name: str, split: str, description: str) -> Callable[[SolidBuilder], SolidBuilder]:
    """Register a z-up solid builder as a category (definition order = CATEGORIES order)."""

    def register(fn: SolidBuilder) -> SolidBuilder:
        CATEGORIES[name] = Family(name, split, description, partial(_build, fn))
        return fn

    return register


def generate(category: str, seed: int) -> trimesh.Trimesh:
    """Deterministic y-up mesh for (category, seed); same inputs give byte-identical arrays.

    The category name is mixed into the seed with CRC32 (stable across processes, unlike
    ``hash()``) so categories sharing a seed do not share random streams. Raises
    :class:`UnknownCategoryError` (a ValueError and a KeyError) naming the available categories.
    """
    family = CATEGORIES.get(category)
    if family is None:
        raise UnknownCategoryError(
            f"unknown category {category!r}; available: {', '.join(CATEGORIES)}"
        )
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    rng = np.random.default_rng([int(seed), zlib.crc32(category.encode("utf-8"))])
    return family.build(rng)


def trained_categories() -> list[str]:
    return [n for n, f in CATEGORIES.items() if f.split == "trained"]


def novel_categories() -> list[str]:
    return [n for n, f in CATEGORIES.items() if f.split == "novel"]


# ============================================================================================
# Trained families.
# ============================================================================================


def _chair_back(rng: np.random.Generator, w: float, d: float, h: float, t: float) -> list[Solid]:
    """Panel or slatted backrest leaning back by a random angle, rooted inside the seat."""
    bh = _u(rng, 0.30, 0.55)
    bt = _u(rng, 0.02, 0.05)
    tilt = math.tan(math.radians(_u(rng, 0.0, 15.0)))
    y0 = d / 2 - bt / 2 - _u(rng, 0.0, 0.01)
    half_w = w / 2 * _u(rng, 0.8, 1.0)
    z0, top = h - t / 2, h + bh

    def yb(z: float) -> float:
        return y0 + (z - h) * tilt

    style = _pick(rng, ["panel", "vertical", "horizontal"])
    if style == "panel":
        return [prism_between((0, yb(z0), z0), (0, yb(top), top), half_w, bt / 2)]
    pw = _u(rng, 0.012, 0.025)
    rh = _u(rng, 0.04, 0.10)
    rail_z = top - rh / 2
    parts = [
        prism_between((sx * (half_w - pw), yb(z0), z0), (sx * (half_w - pw), yb(top), top), pw, pw)
        for sx in (-1.0, 1.0)
    ]
    parts.append(box((2 * (half_w - pw), bt, rh), (0, yb(rail_z), rail_z)))
    inner = half_w - pw
    if style == "vertical":
        n = _i(rng, 1, 5)
        # Cap the width below the spacing: slats that exactly touch leave zero-volume slivers.
        sw = min(_u(rng, 0.008, 0.03), 0.8 * inner / (n + 1))
        for k in range(n):
            x = -inner + 2 * inner * (k + 1) / (n + 1)
            parts.append(prism_between((x, yb(z0), z0), (x, yb(rail_z), rail_z), sw, 0.3 * bt))
    else:
        n = _i(rng, 1, 3)
        spacing = (top - rh - h) / (n + 1)
        sh = min(_u(rng, 0.02, 0.05), 0.6 * spacing)
        for k in range(n):
            z = h + spacing * (k + 1)
            parts.append(box((2 * inner, 0.6 * bt, sh), (0, yb(z), z)))
    return parts


def _swivel_base(rng: np.random.Generator, top_z: float) -> list[Solid]:
    """Office-chair base: column, star of arms and caster balls (arm ends sink into casters)."""
    n = _i(rng, 4, 5)
    reach = _u(rng, 0.22, 0.32)
    ra = _u(rng, 0.014, 0.02)
    rc = _u(rng, 0.02, 0.03)
    hub_z = _u(rng, rc + ra, 0.10)
    phase = _u(rng, 0.0, 2 * math.pi)
    parts = [
        cylinder_between((0, 0, hub_z), (0, 0, top_z), _u(rng, 0.02, 0.04)),
        box((0.16, 0.16, 0.03), (0, 0, top_z - 0.02)),  # mechanism plate under the seat
    ]
    for k in range(n):
        a = phase + 2 * math.pi * k / n
        end = (reach * math.cos(a), reach * math.sin(a))
        parts.append(capsule((0, 0, hub_z), (end[0], end[1], rc + 0.5 * ra), ra))
        parts.append(sphere((end[0], end[1], rc), rc))
    return parts


@_family("chair", "trained", "seat on four legs or a swivel base, panel or slatted back, arms")
def _chair(rng: np.random.Generator) -> Solid:
    w, d = _u(rng, 0.40, 0.60), _u(rng, 0.38, 0.55)
    t, h = _u(rng, 0.03, 0.08), _u(rng, 0.40, 0.50)
    seat_mid = h - t / 2
    parts = [box((w, d, t), (0, 0, seat_mid))]
    if _chance(rng, 0.25):
        parts += _swivel_base(rng, seat_mid)
    else:
        legs = draw_leg_style(rng, 0.012, 0.028)
        inset = _u(rng, legs.radius + 0.003, 0.06)
        xy = rect_corners(w / 2 - inset, d / 2 - inset)
        parts += leg_set(legs, xy, 0.0, seat_mid)
        if _chance(rng, 0.4):
            z = _u(rng, 0.08, 0.22)
            pairs = ALL_EDGE_PAIRS if _chance(rng, 0.5) else SIDE_PAIRS
            parts += stretchers(legs, xy, 0.0, seat_mid, z, pairs)
    parts += _chair_back(rng, w, d, h, t)
    if _chance(rng, 0.35):
        aw, ah = _u(rng, 0.03, 0.06), _u(rng, 0.18, 0.26)
        x, y = w / 2 - aw / 2, -d / 2 + _u(rng, 0.04, 0.1)
        arm = [
            prism_between((x, y, seat_mid), (x, y, h + ah), aw / 2, aw / 2),
            box_span(
                (x - aw / 2, -d / 2 - 0.01, h + ah - 0.02),
                (x + aw / 2, d / 2 - 0.05, h + ah + 0.01),
            ),
        ]
        parts += mirror_x(arm)
    return union(parts)


@_family("table", "trained", "rectangular or round top on legs, pedestal(s) or trestles")
def _table(rng: np.random.Generator) -> Solid:
    h, t = _u(rng, 0.65, 0.80), _u(rng, 0.025, 0.06)
    top_mid = h - t / 2
    round_top = _chance(rng, 0.3)
    if round_top:
        r = _u(rng, 0.35, 0.6)
        parts = [cylinder_between((0, 0, h - t), (0, 0, h), r, SEGMENTS)]
        half_x = half_y = r / math.sqrt(2)
        style = _pick(rng, ["legs", "pedestal"])
    else:
        w = _u(rng, 0.8, 1.8)
        d = _u(rng, 0.5, min(1.0, w))
        parts = [box((w, d, t), (0, 0, top_mid))]
        half_x, half_y = w / 2, d / 2
        style = _pick(rng, ["legs", "pedestal", "trestle"], [3, 1, 1])

    if style == "legs":
        legs = draw_leg_style(rng, 0.015, 0.04, max_splay=0.06)
        inset = _u(rng, legs.radius + 0.005, 0.12)
        xy = rect_corners(half_x - inset, half_y - inset)
        parts += leg_set(legs, xy, 0.0, top_mid)
        if _chance(rng, 0.5):  # apron: rails just under the top, between leg tops
            ah, at = _u(rng, 0.05, 0.12), _u(rng, 0.015, 0.03)
            parts += [
                rail_between(xy[a], xy[b], at, top_mid - ah, top_mid) for a, b in ALL_EDGE_PAIRS
            ]
        if _chance(rng, 0.25):  # lower shelf spanning the leg axes
            z = _u(rng, 0.1, 0.25)
            p = leg_point(legs, xy[3][0], xy[3][1], 0.0, top_mid, z)
            parts.append(box((2 * p[0], 2 * p[1], 0.02), (0, 0, z)))
    elif style == "pedestal":
        xs = [-0.55 * half_x, 0.55 * half_x] if (not round_top and half_x > 0.6) else [0.0]
        rc = _u(rng, 0.035, 0.08)
        taper = _u(rng, 0.5, 1.2)
        foot_r = min(half_x, half_y) * _u(rng, 0.5, 0.8)
        ft = _u(rng, 0.02, 0.05)
        cross = _chance(rng, 0.4)
        for x in xs:
            parts.append(
                cylinder_between(
                    (x, 0, ft - 0.005), (x, 0, top_mid), rc * taper, SEGMENTS, r_end=rc
                )
            )
            if cross:
                parts += [
                    box((2 * foot_r, 0.06, ft), (x, 0, ft / 2)),
                    box((0.06, 2 * foot_r, ft), (x, 0, ft / 2)),
                ]
            else:
                parts.append(cylinder_between((x, 0, 0), (x, 0, ft), foot_r, SEGMENTS))
    else:  # trestle: two end frames joined by a stretcher beam
        pt = _u(rng, 0.03, 0.06)
        x = half_x - _u(rng, 0.05, 0.15)
        depth = 2 * half_y * _u(rng, 0.3, 0.7)
        foot_h = _u(rng, 0.03, 0.07)
        zs = _u(rng, 0.15, 0.45)
        for sx in (-1.0, 1.0):
            parts.append(
                box_span(
                    (sx * x - pt / 2, -depth / 2, foot_h - 0.005),
                    (sx * x + pt / 2, depth / 2, top_mid),
                )
            )
            parts.append(box((1.6 * pt, 1.7 * half_y, foot_h), (sx * x, 0, foot_h / 2)))
        parts.append(box((2 * x, 0.04, 0.05), (0, 0, zs)))
    return union(parts)


@_family("sofa", "trained", "upholstered base, backrest, arms, 1-3 seat cushions, feet")
def _sofa(rng: np.random.Generator) -> Solid:
    w, d = _u(rng, 1.4, 2.4), _u(rng, 0.75, 1.0)
    seat_h = _u(rng, 0.38, 0.48)
    ct = _u(rng, 0.08, 0.16)
    clearance = _u(rng, 0.0, 0.15)
    if clearance < 0.04:
        clearance = 0.0
    back_top = _u(rng, 0.70, 0.95)
    bt = _u(rng, 0.15, 0.25)
    rr = _u(rng, 0.01, 0.06)  # upholstery roundness
    base_top = seat_h - ct
    arms = _pick(rng, ["two", "none"], [5, 1]) == "two"
    aw = _u(rng, 0.10, 0.25) if arms else 0.0
    arm_top = _u(rng, max(seat_h + 0.12, 0.55), 0.72)
    z0 = clearance + 0.005 if clearance else 0.0

    # Hidden parts are pulled in by ``e`` wherever they would share a rounded edge with a
    # visible part: identical curved surfaces triangulated differently leave near-coincident
    # vertices in the union.
    e = 0.005
    side = w / 2 - (e if arms else 0.0)
    parts = [
        rounded_box((-side, -d / 2, z0 + e), (side, d / 2 - e, base_top + 0.01), rr),
        rounded_box((-side, d / 2 - bt, z0 + e), (side, d / 2, back_top), rr),
    ]
    if arms:
        parts += mirror_x([rounded_box((w / 2 - aw, -d / 2, z0), (w / 2, d / 2, arm_top), rr)])
    inner = w / 2 - aw
    n = min(_i(rng, 1, 3), max(1, int(2 * inner / 0.5)))
    gap = 0.01
    seat_w = (2 * inner - gap * (n + 1)) / n
    back_cushions = _chance(rng, 0.5)
    bct = _u(rng, 0.08, 0.16)
    for k in range(n):
        x0 = -inner + gap + k * (seat_w + gap)
        parts.append(
            rounded_box(
                (x0, -d / 2 + 0.02, base_top - 0.01),
                (x0 + seat_w, d / 2 - bt + 0.02, seat_h),
                max(rr, 0.02),
            )
        )
        if back_cushions:
            parts.append(
                rounded_box(
                    (x0, d / 2 - bt - bct, seat_h - 0.02),
                    (x0 + seat_w, d / 2 - bt + 0.02, back_top - 0.04),
                    max(rr, 0.03),
                )
            )
    if clearance:
        legs = draw_leg_style(rng, 0.015, 0.03, max_splay=0.02)
        inset = legs.radius + _u(rng, 0.02, 0.06)
        xy = rect_corners(w / 2 - inset, d / 2 - inset)
        if w > 1.9:
            xy += [(0.0, -d / 2 + inset), (0.0, d / 2 - inset)]
        parts += leg_set(legs, xy, 0.0, clearance + 0.03)
    return union(parts)


@_family("bed", "trained", "frame on legs, mattress, headboard, optional footboard, pillows")
def _bed(rng: np.random.Generator) -> Solid:
    length, width = _u(rng, 1.9, 2.2), _u(rng, 0.9, 2.0)
    leg_h = _u(rng, 0.0, 0.3)
    if leg_h < 0.06:
        leg_h = 0.0  # platform bed
    frame_h = _u(rng, 0.1, 0.25)
    frame_top = leg_h + frame_h
    mattress_top = frame_top + _u(rng, 0.15, 0.3)
    inset = _u(rng, 0.0, 0.04)
    head_t = _u(rng, 0.04, 0.1)
    head_top = mattress_top + _u(rng, 0.3, 0.8)
    hw = width / 2 + _u(rng, 0.0, 0.05)
    y_head = length / 2

    parts = [
        box_span((-width / 2, -length / 2, leg_h), (width / 2, length / 2, frame_top)),
        rounded_box(
            (-width / 2 + inset, -length / 2 + inset, frame_top - 0.01),
            (width / 2 - inset, length / 2 - 0.01, mattress_top),
            _u(rng, 0.02, 0.08),
        ),
    ]
    head_bottom = 0.0 if _chance(rng, 0.5) else leg_h + 0.01
    parts.append(box_span((-hw, y_head - 0.01, head_bottom), (hw, y_head + head_t, head_top)))
    if _chance(rng, 0.4):  # rounded crest along the headboard
        y = y_head + head_t / 2 - 0.005
        parts.append(
            cylinder_between(
                (-hw, y, head_top), (hw, y, head_top), head_t / 2 + 0.01, SMALL_SEGMENTS
            )
        )
    if _chance(rng, 0.4):
        foot_top = frame_top + _u(rng, 0.05, 0.4)
        parts.append(
            box_span((-hw, -length / 2 - head_t, head_bottom), (hw, -length / 2 + 0.01, foot_top))
        )
    if leg_h:
        legs = draw_leg_style(rng, 0.025, 0.05, max_splay=0.0)
        xy = rect_corners(width / 2 - legs.radius - 0.02, length / 2 - legs.radius - 0.02)
        parts += leg_set(legs, xy, 0.0, leg_h + 0.02)
    n_pillows = 2 if width > 1.3 else 1
    pw = (width - 2 * inset) / n_pillows - 0.06
    pd, ph = _u(rng, 0.3, 0.45), _u(rng, 0.08, 0.15)
    for k in range(n_pillows):
        x0 = -width / 2 + inset + 0.03 + k * (pw + 0.06)
        parts.append(
            rounded_box(
                (x0, y_head - 0.05 - pd, mattress_top - 0.03),
                (x0 + pw, y_head - 0.05, mattress_top + ph),
                0.04,
            )
        )
    return union(parts)


def _pull(style: str, at: Point) -> Solid:
    """Door/drawer handle sticking out toward -y from the panel face at ``at``."""
    x, y, z = at
    if style == "knob":
        return cylinder_between((x, y + 0.003, z), (x, y - 0.025, z), 0.012)
    hx, hz = (0.008, 0.06) if style == "vertical" else (0.06, 0.008)
    return box_span((x - hx, y - 0.02, z - hz), (x + hx, y + 0.003, z + hz))


@_family("cabinet", "trained", "box body with drawers and doors, handles, plinth or legs")
def _cabinet(rng: np.random.Generator) -> Solid:
    w, d, h = _u(rng, 0.5, 1.2), _u(rng, 0.35, 0.6), _u(rng, 0.6, 1.9)
    base = _pick(rng, ["plinth", "legs", "none"])
    z0 = {"plinth": _u(rng, 0.05, 0.1), "legs": _u(rng, 0.08, 0.2), "none": 0.0}[base]
    top = z0 + h
    parts = [box_span((-w / 2, -d / 2, z0), (w / 2, d / 2, top))]
    if base == "plinth":
        parts.append(
            box_span((-w / 2 + 0.03, -d / 2 + 0.04, 0.0), (w / 2 - 0.03, d / 2 - 0.02, z0 + 0.01))
        )
    elif base == "legs":
        legs = draw_leg_style(rng, 0.015, 0.03, max_splay=0.03)
        inset = legs.radius + 0.01
        parts += leg_set(legs, rect_corners(w / 2 - inset, d / 2 - inset), 0.0, z0 + 0.02)
    pt = _u(rng, 0.01, 0.02)
    if _chance(rng, 0.5):  # overhanging top board
        oh = _u(rng, 0.01, 0.04)
        parts.append(
            box_span(
                (-w / 2 - oh, -d / 2 - pt - oh, top - 0.005),
                (w / 2 + oh, d / 2, top + _u(rng, 0.015, 0.04)),
            )
        )

    cols = 1 if w < 0.6 else _i(rng, 1, 3)
    n_drawers = _i(rng, 0, 4)
    drawer_h = _u(rng, 0.1, 0.2)
    n_drawers = min(n_drawers, int(0.8 * h / drawer_h))
    door_h = h - n_drawers * drawer_h
    if door_h < 0.15:  # too short for a door: give the space to the drawers
        drawer_h, door_h = h / max(n_drawers, 1), 0.0
        n_drawers = max(n_drawers, 1)
    gap, front_y = 0.004, -d / 2
    knobs = _chance(rng, 0.5)
    col_w = w / cols
    rows = [(z0, z0 + door_h, "door")] if door_h else []
    rows += [
        (z0 + door_h + k * drawer_h, z0 + door_h + (k + 1) * drawer_h, "drawer")
        for k in range(n_drawers)
    ]
    for za, zb, kind in rows:
        for c in range(cols):
            xa, xb = -w / 2 + c * col_w, -w / 2 + (c + 1) * col_w
            parts.append(
                box_span((xa + gap, front_y - pt, za + gap), (xb - gap, front_y + 0.003, zb - gap))
            )
            if kind == "door":
                hx = xb - 0.05 if (cols == 1 or c < cols / 2) else xa + 0.05
                hz = za + 0.7 * (zb - za) if zb - za > 0.5 else (za + zb) / 2
            else:
                hx, hz = (xa + xb) / 2, (za + zb) / 2
            style = "knob" if knobs else ("vertical" if kind == "door" else "horizontal")
            parts.append(_pull(style, (hx, front_y - pt, hz)))
    return union(parts)


def _shade(rng: np.random.Generator, size: float) -> tuple[Solid, float]:
    """Hollow frustum shade along local +z: closed cap at z in [0, cap], opening at z = height.

    Returns the shade and its cap thickness (where the stem should end).
    """
    r_open = size * _u(rng, 0.8, 1.2)
    r_cap = r_open * _u(rng, 0.3, 0.9)
    height = size * _u(rng, 0.8, 1.6)
    wall = size * _u(rng, 0.04, 0.07)
    cap = size * _u(rng, 0.08, 0.15)
    slope = (r_open - r_cap) / height
    extra = 0.1 * height
    outer = cylinder_between((0, 0, 0), (0, 0, height), r_cap, SEGMENTS, r_end=r_open)
    inner = cylinder_between(
        (0, 0, cap),
        (0, 0, height + extra),
        r_cap + slope * cap - wall,
        SEGMENTS,
        r_end=r_open + slope * extra - wall,
    )
    parts = [difference(outer, [inner])]
    if _chance(rng, 0.7):  # bulb hanging from the cap on a socket
        socket = cylinder_between((0, 0, cap / 2), (0, 0, cap + 0.25 * height), 0.15 * r_cap)
        bulb = sphere((0, 0, cap + 0.25 * height + 0.12 * r_open), 0.2 * r_open)
        parts += [socket, bulb]
    return union(parts), cap


@_family("lamp", "trained", "weighted base, straight pole or jointed arm, hollow shade")
def _lamp(rng: np.random.Generator) -> Solid:
    style = _pick(rng, ["floor", "desk", "arm"])
    height = _u(rng, 1.2, 1.7) if style == "floor" else _u(rng, 0.35, 0.6)
    bt = height * _u(rng, 0.02, 0.05)
    rb = height * _u(rng, 0.1, 0.22)
    rp = height * _u(rng, 0.008, 0.018)
    if _chance(rng, 0.7):
        parts = [
            cylinder_between((0, 0, 0), (0, 0, bt), rb, SEGMENTS, r_end=rb * _u(rng, 0.6, 1.0))
        ]
    else:
        parts = [box((1.6 * rb, 1.6 * rb, bt), (0, 0, bt / 2))]
    shade_size = height * (_u(rng, 0.08, 0.13) if style == "floor" else _u(rng, 0.1, 0.17))
    shade, cap = _shade(rng, shade_size)
    if style == "arm":
        j1 = _vec((0, height * _u(rng, -0.2, 0.2), height * _u(rng, 0.4, 0.6)))
        a = math.radians(_u(rng, 40, 100))
        l2 = height * _u(rng, 0.35, 0.6)
        j2 = j1 + l2 * np.array([0.0, -math.sin(a), math.cos(a)])
        tilt = math.radians(_u(rng, 0, 50))
        direction = (0.0, -math.sin(tilt), -math.cos(tilt))
        parts += [
            cylinder_between((0, 0, bt / 2), j1, rp),
            cylinder_between(j1, j2, rp),
            sphere(j1, 1.6 * rp),
            sphere(j2, 1.6 * rp),
        ]
        parts.append(place(shade, j2 - 0.5 * cap * np.array(direction), direction))
    else:
        parts.append(cylinder_between((0, 0, bt / 2), (0, 0, height), rp))
        if _chance(rng, 0.7):  # shade over the bulb, opening downward
            parts.append(place(shade, (0, 0, height + cap / 2), (0, 0, -1)))
        else:  # torchiere: bowl opening upward
            parts.append(place(shade, (0, 0, height - cap / 2), (0, 0, 1)))
    return union(parts)


@_family("bottle", "trained", "revolved body with shoulder, neck and lip, optional cap")
def _bottle(rng: np.random.Generator) -> Solid:
    height = _u(rng, 0.2, 0.35)
    r = height * _u(rng, 0.12, 0.25)
    body_h = height * _u(rng, 0.4, 0.65)
    neck_r = r * _u(rng, 0.22, 0.5)
    shoulder_h = height * _u(rng, 0.08, 0.25)
    neck_top = height
    lip = _u(rng, 0.005, 0.012)
    bevel = 0.1 * r
    waist = _u(rng, 0.85, 1.05)
    prof = [(0.0, 0.0), (r - bevel, 0.0), (r, bevel), (r * waist, body_h / 2), (r, body_h)]
    shoulder_power = _u(rng, 0.5, 2.0)
    for k in range(1, 8):  # smooth shoulder from body radius down to the neck
        s = k / 8
        rad = neck_r + (r - neck_r) * math.cos(math.pi / 2 * s**shoulder_power)
        prof.append((rad, body_h + shoulder_h * s))
    prof += [
        (neck_r, body_h + shoulder_h),
        (neck_r, neck_top - lip),
        (neck_r * 1.18, neck_top - lip),
        (neck_r * 1.18, neck_top),
        (0.0, neck_top),
    ]
    parts = [revolve(prof)]
    if _chance(rng, 0.5):
        cap_h = _u(rng, 0.015, 0.04)
        parts.append(
            cylinder_between(
                (0, 0, neck_top - lip - 0.004), (0, 0, neck_top + cap_h), neck_r * 1.25, 24
            )
        )
    return union(parts)


@_family("mug", "trained", "hollow cylinder with a bottom and a genus-1 handle")
def _mug(rng: np.random.Generator) -> Solid:
    r, h = _u(rng, 0.035, 0.055), _u(rng, 0.07, 0.12)
    wall, bottom = _u(rng, 0.003, 0.007), _u(rng, 0.005, 0.012)
    r_top = r * _u(rng, 1.0, 1.15)
    slope = (r_top - r) / h
    body = cylinder_between((0, 0, 0), (0, 0, h), r, SEGMENTS, r_end=r_top)
    extra = 0.01
    cavity = cylinder_between(
        (0, 0, bottom),
        (0, 0, h + extra),
        r + slope * bottom - wall,
        SEGMENTS,
        r_end=r_top + slope * extra - wall,
    )

    # Handle: an upright torus (optionally stretched vertically) cut to a "C" whose ends cross the
    # whole wall, so after the union it is attached at two places (genus 1).
    major = h * _u(rng, 0.25, 0.4)
    tube = major * _u(rng, 0.12, 0.25)
    cz = h * _u(rng, 0.45, 0.55)
    room = min(cz, h - cz) - tube - 0.003  # keep both handle ends below the rim
    stretch = min(_u(rng, 1.0, 1.4), room / major)
    r_mid = r + slope * cz
    x_cut = r - wall  # at or inside the inner wall everywhere, so the ends pierce the wall
    k_max = 1.0 - (r_mid - x_cut + tube + 0.003) / major
    k = min(_u(rng, 0.1, 0.5), k_max)
    handle = (
        torus(major, tube, SEGMENTS)
        .rotate((90.0, 0.0, 0.0))
        .scale((1.0, 1.0, stretch))
        .translate((r_mid + k * major, 0.0, cz))
        .trim_by_plane((1.0, 0.0, 0.0), x_cut)
    )
    return difference(union([body, handle]), [cavity])


def _wing(
    root_le: Point,
    tip_le: Point,
    chord: tuple[float, float],
    thick: tuple[float, float],
    vertical: bool = False,
) -> Solid:
    """Tapered lifting surface with a diamond section (hull of root and tip sections).

    Chord runs toward -x from the leading edge; thickness is along z (or y for a fin).
    """
    axis = np.array([0.0, 1.0, 0.0]) if vertical else np.array([0.0, 0.0, 1.0])
    pts = []
    for le, c, t in ((_vec(root_le), chord[0], thick[0]), (_vec(tip_le), chord[1], thick[1])):
        back = np.array([c, 0.0, 0.0])
        pts += [le, le - back, le - 0.3 * back + axis * t / 2, le - 0.3 * back - axis * t / 2]
    return hull(pts)


def _mirror_across_y0(parts: list[Solid], shift: float) -> list[Solid]:
    """Parts plus mirror images for the other side, nudged by ``shift`` along y.

    The wing roots cross y = 0 so the two halves overlap. An exact mirror would make the halves
    intersect precisely on the y = 0 plane, where the fuselage and fin also have vertices and
    edges; such degenerate contacts leave near-coincident vertices in the union.
    """
    return parts + [p.mirror((0.0, 1.0, 0.0)).translate((0.0, shift, 0.0)) for p in parts]


@_family("airplane", "trained", "tapered fuselage, swept wings, tailplane and fin, engines")
def _airplane(rng: np.random.Generator) -> Solid:
    length = 1.0
    rf = length * _u(rng, 0.04, 0.08)
    rn, rt = rf * _u(rng, 0.5, 0.9), rf * _u(rng, 0.2, 0.4)
    tail_z = rf - rt
    # Fuselage: hull of spheres, each turned about x so that no hull vertex or edge lies on the
    # y = 0 plane, where the fin and the wing-half overlaps would meet it degenerately.
    stations = [
        (length / 2 - rn, 0.0, rn),
        (0.2 * length, 0.0, rf),
        (-0.15 * length, 0.0, rf),
        (-length / 2 + rt, tail_z, rt),
    ]
    parts = [
        Manifold.batch_hull(
            [
                Manifold.sphere(r, 20).rotate((13.0, 0.0, 0.0)).translate((x, 0.0, z))
                for x, z, r in stations
            ]
        )
    ]

    # Main wings.
    cr = length * _u(rng, 0.15, 0.3)
    ct = cr * _u(rng, 0.2, 0.6)
    span = length * _u(rng, 0.4, 0.7)
    sweep = length * _u(rng, 0.0, 0.25)
    dihedral = length * _u(rng, -0.02, 0.08)
    zw = rf * _u(rng, -0.6, 0.5)
    tw = length * _u(rng, 0.015, 0.03)
    le_x = length * _u(rng, -0.1, 0.1) + cr / 2
    wing = _wing(
        (le_x, -0.2 * rf, zw), (le_x - sweep, span, zw + dihedral), (cr, ct), (tw, 0.4 * tw)
    )
    wings = [wing]
    if _chance(rng, 0.7):  # under-wing engine nacelles
        re = length * _u(rng, 0.02, 0.04)
        le_len = length * _u(rng, 0.1, 0.18)
        fracs = [0.35] if _chance(rng, 0.6) else [0.3, 0.6]
        for f in fracs:
            x_le = le_x - sweep * f
            zc = zw + dihedral * f - 0.7 * re
            wings.append(
                cylinder_between(
                    (x_le + 0.3 * le_len, span * f, zc),
                    (x_le - 0.7 * le_len, span * f, zc),
                    re,
                    16,
                    r_end=0.8 * re,
                )
            )
    parts += _mirror_across_y0(wings, 0.002 * length)

    # Tail: vertical fin on the upswept tail cone, tailplane low or on top of the fin (T-tail).
    fin_c = length * _u(rng, 0.1, 0.18)
    fin_h = length * _u(rng, 0.08, 0.18)
    fin_sweep = fin_h * _u(rng, 0.3, 1.2)
    fin_le = -length / 2 + rt + fin_c
    fin_y = 0.001 * length  # off the symmetry plane, for the same reason as the fuselage
    fin_tip = (fin_le - fin_sweep, fin_y, rf + fin_h)
    parts.append(
        _wing(
            (fin_le, fin_y, tail_z),
            fin_tip,
            (fin_c, 0.5 * fin_c),
            (0.02 * length, 0.01 * length),
            vertical=True,
        )
    )
    sc = length * _u(rng, 0.06, 0.12)
    ss = length * _u(rng, 0.12, 0.22)
    if _chance(rng, 0.25):
        root = (fin_tip[0] - 0.02 * fin_c, -0.005 * length, fin_tip[2] - 0.005 * length)
        sc = min(sc, 0.5 * fin_c)
    else:
        root = (-length / 2 + rt + 1.1 * sc, -0.005 * length, tail_z)
    tip = (root[0] - 0.5 * sc, ss, root[2] + 0.01 * length)
    stab = _wing(root, tip, (sc, 0.5 * sc), (0.012 * length, 0.006 * length))
    parts += _mirror_across_y0([stab], 0.002 * length)
    return union(parts)


@_family("car", "trained", "slanted body with wheel arches, cabin, four wheels")
def _car(rng: np.random.Generator) -> Solid:
    length = _u(rng, 0.9, 1.1)
    width = length * _u(rng, 0.38, 0.48)
    rw = length * _u(rng, 0.07, 0.1)
    ww = length * _u(rng, 0.06, 0.09)
    zc = rw * _u(rng, 0.5, 0.9)
    body_top = max(zc + length * _u(rng, 0.12, 0.2), 2.3 * rw)
    front_bevel, rear_bevel = length * _u(rng, 0.03, 0.12), length * _u(rng, 0.0, 0.08)
    hw = width / 2
    body = hull(
        [(x, y, zc) for x in (-length / 2, length / 2) for y in (-hw, hw)]
        + [
            (x, y, body_top)
            for x in (-length / 2 + rear_bevel, length / 2 - front_bevel)
            for y in (-hw, hw)
        ]
    )
    overhang = length * _u(rng, 0.15, 0.22)
    axles = (length / 2 - overhang, -length / 2 + overhang * _u(rng, 0.9, 1.1))
    arches = [
        cylinder_between((x, sy * (hw - 0.4 * ww), rw), (x, sy * (hw + 0.05), rw), 1.12 * rw, 24)
        for x in axles
        for sy in (-1.0, 1.0)
    ]
    parts = [difference(body, arches)]
    hub_caps = _chance(rng, 0.5)
    for x in axles:
        for sy in (-1.0, 1.0):
            parts.append(
                cylinder_between((x, sy * (hw - 0.9 * ww), rw), (x, sy * (hw + 0.01), rw), rw, 24)
            )
            if hub_caps:
                parts.append(
                    cylinder_between((x, sy * hw, rw), (x, sy * (hw + 0.02), rw), 0.5 * rw, 16)
                )

    # Cabin: trapezoid hull; its position/length gives sedan, hatchback, van-like silhouettes.
    cab_len = length * _u(rng, 0.4, 0.7)
    cab_front = length / 2 - front_bevel - length * _u(rng, 0.1, 0.3)
    cab_back = max(cab_front - cab_len, -length / 2 + rear_bevel)
    cab_len = cab_front - cab_back
    cab_h = length * _u(rng, 0.1, 0.17)
    wind = cab_len * _u(rng, 0.15, 0.35)
    rear = cab_len * _u(rng, 0.05, 0.35)
    base_hw, top_hw = hw * 0.92, hw * _u(rng, 0.7, 0.85)
    parts.append(
        hull(
            [(x, y, body_top - 0.01) for x in (cab_back, cab_front) for y in (-base_hw, base_hw)]
            + [
                (x, y, body_top + cab_h)
                for x in (cab_back + rear, cab_front - wind)
                for y in (-top_hw, top_hw)
            ]
        )
    )
    if _chance(rng, 0.2):  # spoiler on two posts
        x = -length / 2 + rear_bevel + 0.03
        z = body_top + 0.03
        parts += [
            box((0.02, 0.02, 0.04), (x, sy * hw * 0.6, body_top + 0.01)) for sy in (-1.0, 1.0)
        ]
        parts.append(box((0.06, 2 * hw * 0.9, 0.01), (x, 0, z)))
    return union(parts)


@_family("monitor", "trained", "thin bezelled screen, back housing, neck and base")
def _monitor(rng: np.random.Generator) -> Solid:
    w = _u(rng, 0.4, 0.7)
    hs = w * _u(rng, 0.5, 0.65)
    ts = _u(rng, 0.01, 0.03)
    bt = _u(rng, 0.01, 0.02)
    zc = bt + _u(rng, 0.04, 0.15) + hs / 2
    bezel = _u(rng, 0.005, 0.02)
    screen = difference(
        box((w, ts, hs), (0, 0, zc)),
        [box((w - 2 * bezel, 0.004, hs - 2 * bezel), (0, -ts / 2, zc))],
    )
    parts = [screen]
    nx, ny = _u(rng, 0.015, 0.04), _u(rng, 0.008, 0.015)
    if _chance(rng, 0.7):
        hd = _u(rng, 0.02, 0.06)
        parts.append(
            box(
                (w * _u(rng, 0.4, 0.8), hd + 0.005, hs * _u(rng, 0.4, 0.8)),
                (0, ts / 2 + hd / 2 - 0.0025, zc),
            )
        )
        neck_top_y = ts / 2 + hd / 2
    else:
        neck_top_y = ts / 2 + 0.5 * ny
    lean = _u(rng, 0.0, 0.06)
    neck_bottom = (0.0, neck_top_y + lean, bt - 0.003)
    parts.append(prism_between(neck_bottom, (0.0, neck_top_y, zc), nx, ny))
    if _chance(rng, 0.5):
        rb = _u(rng, 0.08, 0.14)
        parts.append(
            cylinder_between((0, neck_bottom[1], 0), (0, neck_bottom[1], bt), rb, SEGMENTS)
        )
    else:
        parts.append(
            box((w * _u(rng, 0.3, 0.5), _u(rng, 0.12, 0.22), bt), (0, neck_bottom[1], bt / 2))
        )
    return union(parts)


# ============================================================================================
# Novel families: distinct kinds that reuse parts seen in the trained ones (legs, boards,
# revolved hollows, bent pipes).
# ============================================================================================


@_family("bench", "novel", "long slatted or solid seat on legs or end panels, optional back")
def _bench(rng: np.random.Generator) -> Solid:
    length, d, h = _u(rng, 1.0, 2.0), _u(rng, 0.3, 0.5), _u(rng, 0.4, 0.48)
    st = _u(rng, 0.025, 0.05)
    beam_x = length / 2 - _u(rng, 0.08, 0.2)
    beam_h = _u(rng, 0.04, 0.07)
    beam_top = h - st + 0.005
    parts: list[Solid] = []
    if _chance(rng, 0.5):  # slats along the length, held by two cross beams
        n = _i(rng, 3, 6)
        gap = _u(rng, 0.006, 0.02)
        sw = (d - gap * (n - 1)) / n
        for k in range(n):
            y0 = -d / 2 + k * (sw + gap)
            parts.append(box_span((-length / 2, y0, h - st), (length / 2, y0 + sw, h)))
    else:
        parts.append(box_span((-length / 2, -d / 2, h - st), (length / 2, d / 2, h)))
    for sx in (-1.0, 1.0):
        parts.append(
            box_span(
                (sx * beam_x - 0.025, -d / 2 + 0.01, beam_top - beam_h),
                (sx * beam_x + 0.025, d / 2 - 0.01, beam_top),
            )
        )
    support_top = beam_top - beam_h / 2
    style = _pick(rng, ["legs", "panels", "a-frame"])
    if style == "legs":
        legs = draw_leg_style(rng, 0.015, 0.03, max_splay=0.04)
        xy = rect_corners(beam_x, d / 2 - legs.radius - 0.015)
        parts += leg_set(legs, xy, 0.0, support_top)
        if _chance(rng, 0.5):
            parts += stretchers(legs, xy, 0.0, support_top, _u(rng, 0.1, 0.2), SIDE_PAIRS)
    elif style == "panels":
        pt = _u(rng, 0.025, 0.05)
        for sx in (-1.0, 1.0):
            parts.append(
                box_span(
                    (sx * beam_x - pt / 2, -d / 2 + 0.01, 0.0),
                    (sx * beam_x + pt / 2, d / 2 - 0.01, support_top),
                )
            )
    else:  # two splayed legs per end meeting under the beam
        r = _u(rng, 0.015, 0.03)
        spread = d / 2 * _u(rng, 0.8, 1.3)
        bar_z = _u(rng, 0.1, 0.2)
        bar_y = spread + (0.2 * d - spread) * bar_z / support_top  # leg axis at the bar height
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                parts.append(
                    prism_between(
                        (sx * beam_x, sy * spread, 0.0),
                        (sx * beam_x, sy * 0.2 * d, support_top),
                        r,
                        r,
                    )
                )
            parts.append(box((0.03, 2 * bar_y, 0.03), (sx * beam_x, 0, bar_z)))
    if _chance(rng, 0.5):  # park-bench back: posts rising from the beams, horizontal slats
        back_h = _u(rng, 0.25, 0.45)
        tilt = math.tan(math.radians(_u(rng, 5, 20)))
        y0, z0 = d / 2 - 0.03, beam_top - beam_h
        top = h + back_h
        lean = back_h * tilt
        for sx in (-1.0, 1.0):
            parts.append(
                prism_between((sx * beam_x, y0, z0), (sx * beam_x, y0 + lean, top), 0.02, 0.02)
            )
        half = beam_x + _u(rng, 0.02, 0.1)
        for k in range(_i(rng, 1, 3)):
            z = h + back_h * (0.3 + 0.6 * (k + 1) / 3) - 0.02
            y = y0 + lean * (z - z0) / (top - z0)
            parts.append(box((2 * half, 0.02, _u(rng, 0.03, 0.06)), (0, y, z)))
    return union(parts)


@_family("bowl", "novel", "hollow revolved bowl with rounded sides and optional foot ring")
def _bowl(rng: np.random.Generator) -> Solid:
    r = _u(rng, 0.08, 0.15)
    h = r * _u(rng, 0.3, 0.75)
    wall = _u(rng, 0.004, 0.01)
    rb = r * _u(rng, 0.25, 0.65)
    power = _u(rng, 0.7, 1.5)  # bulge of the side curve
    n = 12

    def side(base_r: float, rim_r: float, z0: float, z1: float) -> list[tuple[float, float]]:
        return [
            (
                base_r + (rim_r - base_r) * math.sin(math.pi / 2 * k / n) ** (1 / power),
                z0 + (z1 - z0) * (1 - math.cos(math.pi / 2 * k / n)),
            )
            for k in range(n + 1)
        ]

    outer = revolve([(0.0, 0.0), *side(rb, r, 0.0, h), (0.0, h)])
    inner_pts = side(rb - wall, r - wall, wall * _u(rng, 1.0, 2.0), h)
    inner = revolve([(0.0, inner_pts[0][1]), *inner_pts, (r - wall, h + 0.02), (0.0, h + 0.02)])
    solid = difference(outer, [inner])
    if _chance(rng, 0.5):  # foot ring under the base
        fh = _u(rng, 0.005, 0.015)
        ring_r = rb * _u(rng, 0.7, 0.95)
        ring = revolve(
            [(ring_r - wall, 0.0), (ring_r, 0.0), (ring_r, fh + 0.002), (ring_r - wall, fh + 0.002)]
        )
        solid = union([solid.translate((0.0, 0.0, fh)), ring])
    return solid


@_family("shelf", "novel", "bookshelf: side panels or posts, boards, back, optional books")
def _shelf(rng: np.random.Generator) -> Solid:
    w, d, h = _u(rng, 0.6, 1.2), _u(rng, 0.25, 0.4), _u(rng, 0.8, 2.0)
    bt = _u(rng, 0.015, 0.03)
    n_inner = min(_i(rng, 2, 6), max(1, int(h / 0.28) - 1))
    kick = _u(rng, 0.0, 0.1)
    levels = [kick + bt / 2] + [kick + (h - kick) * (k + 1) / (n_inner + 1) for k in range(n_inner)]
    levels.append(h - bt / 2)
    if _chance(rng, 0.7):
        parts = [
            box_span((sx * w / 2 - bt / 2, -d / 2, 0.0), (sx * w / 2 + bt / 2, d / 2, h))
            for sx in (-1.0, 1.0)
        ]
        board_w = w
    else:  # open frame on four posts; boards end on the post axes
        p = _u(rng, 0.012, 0.025)
        parts = [
            box_span((x - p, y - p, 0.0), (x + p, y + p, h))
            for x, y in rect_corners(w / 2 - p, d / 2 - p)
        ]
        board_w = w - 2 * p
    parts += [box((board_w, d, bt), (0, 0, z)) for z in levels]
    if _chance(rng, 0.6):
        parts.append(box_span((-w / 2, d / 2 - 0.008, 0.0), (w / 2, d / 2, h)))
    if _chance(rng, 0.3):  # vertical divider through the lower compartments
        x = w * _u(rng, -0.2, 0.2)
        parts.append(box((bt, d, levels[-1] - levels[0]), (x, 0, (levels[0] + levels[-1]) / 2)))
    if _chance(rng, 0.6):  # books standing on some boards, with small gaps between them
        for z0, z1 in zip(levels[:-1], levels[1:], strict=True):
            if not _chance(rng, 0.6):
                continue
            clear = z1 - z0 - bt
            x = -w / 2 + bt + _u(rng, 0.0, 0.3 * w)
            end = x + (w - 2 * bt) * _u(rng, 0.2, 0.6)
            while x < end:
                bw = _u(rng, 0.015, 0.045)
                bh = clear * _u(rng, 0.55, 0.9)
                bd = d * _u(rng, 0.6, 0.9)
                parts.append(
                    box_span(
                        (x, -d / 2 + 0.01, z0 + bt / 2 - 0.003),
                        (x + bw, -d / 2 + 0.01 + bd, z0 + bt / 2 + bh),
                    )
                )
                x += bw + 0.002
    return union(parts)


@_family("faucet", "novel", "base plate, column, gooseneck or straight spout, lever or knobs")
def _faucet(rng: np.random.Generator) -> Solid:
    plate_t = _u(rng, 0.008, 0.02)
    rc = _u(rng, 0.015, 0.03)
    hc = _u(rng, 0.1, 0.25)
    rp = rc * _u(rng, 0.5, 0.9)
    parts = [cylinder_between((0, 0, plate_t - 0.003), (0, 0, hc + rp), rc, 20)]
    if _chance(rng, 0.5):
        parts.append(cylinder_between((0, 0, 0), (0, 0, plate_t), rc * _u(rng, 1.6, 2.5), SEGMENTS))
    else:
        parts.append(
            box((rc * _u(rng, 3.0, 8.0), rc * _u(rng, 2.5, 3.5), plate_t), (0, 0, plate_t / 2))
        )

    if _chance(rng, 0.5):  # gooseneck: a bent pipe from the column top arching forward (-y)
        ra = _u(rng, 0.05, 0.12)
        sweep = _u(rng, 150.0, 200.0)
        # The revolved arc starts at (ra, 0, 0) heading +y; the cyclic axis permutation
        # (x, y, z) -> (z, x - ra, y + hc) (a proper rotation, so winding is kept) moves that
        # start onto the column top heading up, and bends the pipe toward -y.
        arc = torus(ra, rp, 40, sweep).transform(
            np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, -ra], [0.0, 1.0, 0.0, hc]])
        )
        a = math.radians(sweep)
        end = np.array([0.0, ra * math.cos(a) - ra, ra * math.sin(a) + hc])
        tangent = np.array([0.0, -math.sin(a), math.cos(a)])
        parts += [arc, cylinder_between(end - 0.3 * rp * tangent, end + 0.02 * tangent, 1.15 * rp)]
        # Lever on the side of the column.
        z = hc * _u(rng, 0.4, 0.8)
        parts.append(
            capsule(
                (0, 0, z),
                (rc + _u(rng, 0.03, 0.06), 0, z + _u(rng, 0.0, 0.04)),
                _u(rng, 0.005, 0.01),
            )
        )
    else:  # straight spout from the column, nozzle pointing down
        zs = hc * _u(rng, 0.6, 0.9)
        reach = _u(rng, 0.08, 0.2)
        drop = _u(rng, 0.0, 0.04)
        tip = (0.0, -reach, zs - drop)
        # The elbow sphere is a bit fatter than the pipes: equal radii would put the pipe rims
        # exactly on the sphere and leave near-coincident vertices in the union.
        parts += [
            cylinder_between((0, 0, zs), tip, rp),
            sphere(tip, 1.08 * rp),
            cylinder_between(tip, (tip[0], tip[1], tip[2] - _u(rng, 0.01, 0.03)), rp),
        ]
        if _chance(rng, 0.5):  # single lever on top
            parts.append(
                capsule(
                    (0, 0, hc + rp), (0, _u(rng, 0.03, 0.08), hc + rp + 0.03), _u(rng, 0.005, 0.01)
                )
            )
        else:  # two cross knobs on short side columns joined to the main one
            s = rc + _u(rng, 0.03, 0.06)
            kz = _u(rng, 0.03, 0.06)
            for sx in (-1.0, 1.0):
                parts += [
                    cylinder_between((sx * s, 0, 0), (sx * s, 0, plate_t + kz), 0.6 * rc),
                    box((0.05, 0.008, 0.008), (sx * s, 0, plate_t + kz)),
                    box((0.008, 0.05, 0.008), (sx * s, 0, plate_t + kz)),
                    cylinder_between((0, 0, plate_t + 0.01), (sx * s, 0, plate_t + 0.01), 0.5 * rc),
                ]
    return union(parts)
