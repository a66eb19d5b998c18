"""The built-in scenes of the sample generator.

:func:`street_scene` (outdoor: roads, sidewalks, building rows with windows and shop fronts,
parked cars, kiosks, lamp poles, sky), :func:`room_scene` (indoor room 6 x 5 x 3 m with
furniture and posters) and :func:`tiny_scene` (a few quads, for tests). :func:`build_scene`
picks one by name.
"""

from __future__ import annotations

import numpy as np

from vio_core.errors import lookup

from .scenes import Material, Scene, SceneBuilder

ASPHALT = Material("gravel", tile_m=1.6, tint=(0.42, 0.42, 0.44), contrast=1.3, macro="clouds", macro_tile_m=30.0,
                   macro_strength=0.35)
PAVING = Material("brick", tile_m=2.4, tint=(0.78, 0.76, 0.72), contrast=0.9, macro="clouds", macro_tile_m=20.0,
                  macro_strength=0.25)
CURB = Material("gravel", tile_m=1.0, tint=(0.75, 0.75, 0.74))
PAINT = Material("gravel", tile_m=1.0, tint=(1.05, 1.05, 1.02), contrast=0.25)
FACADES = (
    Material("brick", tile_m=2.2, tint=(0.86, 0.46, 0.36), macro="clouds", macro_tile_m=18.0, macro_strength=0.3),
    Material("brick", tile_m=2.6, tint=(0.93, 0.83, 0.6), macro="clouds", macro_tile_m=15.0, macro_strength=0.3),
    Material("gravel", tile_m=3.0, tint=(0.82, 0.8, 0.76), contrast=0.8, macro="clouds", macro_tile_m=14.0,
             macro_strength=0.35),
    Material("gravel", tile_m=1.2, tint=(1.3, 1.2, 1.05), contrast=0.35, macro="clouds", macro_tile_m=10.0,
             macro_strength=0.3),
    Material("gravel", tile_m=2.0, tint=(0.95, 1.0, 1.1), contrast=0.5, macro="clouds", macro_tile_m=20.0,
             macro_strength=0.35),
    Material("grass", tile_m=2.5, tint=(0.6, 0.7, 0.55), contrast=1.0, macro="clouds", macro_tile_m=12.0,
             macro_strength=0.3),
)
WINDOW_PHOTOS = ("hubble", "camera", "clock", "text", "coins", "retina", "cat", "cell")
SHOP_PHOTOS = ("astronaut", "rocket", "coffee", "chelsea", "ihc", "cat", "retina", "hubble", "clock", "camera",
               "coins")
CAR_PAINTS = ((0.8, 0.15, 0.12), (0.15, 0.3, 0.75), (0.85, 0.85, 0.85), (0.2, 0.2, 0.22), (0.9, 0.75, 0.2),
              (0.25, 0.55, 0.3))


def _window_material(photo: str) -> Material:
    return Material(photo, tile_m=5.0, tint=(0.42, 0.5, 0.62), contrast=1.4)


def _car_material(tint) -> Material:
    return Material("gravel", tile_m=1.5, tint=tuple(tint), contrast=0.35)


def _facade_windows(b: SceneBuilder, origin, u_dir, length: float, height: float) -> None:
    """Shop fronts on the ground floor and a window grid above, on the facade plane that
    starts at ``origin`` (ground level) and runs ``length`` m along unit ``u_dir`` (the
    facade's right direction seen from the street)."""
    rng = b.rng
    down = np.array([0.0, 0.0, -1.0])
    origin = np.asarray(origin, float)
    u_dir = np.asarray(u_dir, float)
    # ground floor: shop windows / posters and doors
    x = rng.uniform(0.6, 1.5)
    while x + 2.0 < length - 0.5:
        w = rng.uniform(1.8, 3.2)
        if x + w > length - 0.5:
            break
        photo = SHOP_PHOTOS[rng.integers(len(SHOP_PHOTOS))]
        h = rng.uniform(1.8, 2.4)
        centre = origin + (x + w / 2) * u_dir + np.array([0, 0, 0.5 + h / 2])
        b.decal(centre, u_dir, down, w, h, Material(photo, tint=tuple(rng.uniform(0.8, 1.0, 3))), lift=0.02)
        x += w + rng.uniform(0.8, 2.0)
    # upper floors: window grid
    floor_h = rng.uniform(2.9, 3.4)
    win_w, win_h = rng.uniform(0.9, 1.5), rng.uniform(1.3, 1.8)
    pitch = rng.uniform(2.2, 3.2)
    n_cols = int((length - 1.0) // pitch)
    if n_cols < 1:
        return
    margin = (length - (n_cols - 1) * pitch) / 2
    z = 3.6 + floor_h / 2
    while z + win_h / 2 < height - 0.8:
        for k in range(n_cols):
            photo = WINDOW_PHOTOS[rng.integers(len(WINDOW_PHOTOS))]
            centre = origin + (margin + k * pitch) * u_dir + np.array([0, 0, z])
            b.decal(centre, u_dir, down, win_w, win_h, _window_material(photo), lift=0.02, fit=False)
        z += floor_h


def _building(b: SceneBuilder, lo, hi, facades: tuple[str, ...]) -> None:
    """A building box with windows on the faces named in ``facades`` ("+x", "-x", "+y", "-y")."""
    rng = b.rng
    mat = FACADES[rng.integers(len(FACADES))]
    b.box(lo, hi, mat, skip=("bottom", "top"))
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    x0, y0, _ = lo
    x1, y1, z1 = hi
    face_lines = {  # origin at ground, right direction seen from outside, length
        "+x": ((x1, y0, 0.0), (0, 1, 0), y1 - y0),
        "-x": ((x0, y1, 0.0), (0, -1, 0), y1 - y0),
        "+y": ((x1, y1, 0.0), (-1, 0, 0), x1 - x0),
        "-y": ((x0, y0, 0.0), (1, 0, 0), x1 - x0),
    }
    for f in facades:
        o, d, length = face_lines[f]
        _facade_windows(b, np.array(o), np.array(d, float), length, z1)


def _building_row(b: SceneBuilder, axis: int, start: float, end: float, front: float, direction: int,
                  facade: str, depth: float = 12.0) -> None:
    """Buildings along ``axis`` (0: x, 1: y) from ``start`` to ``end``, their street-side
    facade at coordinate ``front`` on the other axis, extending ``depth`` m away from the
    street in ``direction`` (+1 / -1)."""
    rng = b.rng
    pos = start
    while pos < end - 1.0:
        width = min(rng.uniform(8.0, 18.0), end - pos)
        if end - (pos + width) < 4.0:
            width = end - pos
        setback = rng.uniform(0.0, 0.8)
        height = rng.uniform(7.0, 22.0)
        f = front + direction * setback
        back = front + direction * depth
        lo_o, hi_o = sorted((f, back))
        if axis == 1:
            lo, hi = (lo_o, pos, 0.0), (hi_o, pos + width, height)
        else:
            lo, hi = (pos, lo_o, 0.0), (pos + width, hi_o, height)
        _building(b, lo, hi, (facade,))
        pos += width


def _car(b: SceneBuilder, center_xy, heading_axis: int) -> None:
    rng = b.rng
    paint = _car_material(CAR_PAINTS[rng.integers(len(CAR_PAINTS))])
    glass = _window_material(WINDOW_PHOTOS[rng.integers(len(WINDOW_PHOTOS))])
    dark = Material("gravel", tile_m=1.0, tint=(0.12, 0.12, 0.13))
    length, width = rng.uniform(3.9, 4.7), rng.uniform(1.7, 1.9)
    half = np.array([length / 2, width / 2]) if heading_axis == 0 else np.array([width / 2, length / 2])
    c = np.asarray(center_xy, float)
    lo, hi = c - half, c + half
    b.box((lo[0] + 0.15, lo[1] + 0.15, 0.0), (hi[0] - 0.15, hi[1] - 0.15, 0.32), dark)
    b.box((lo[0], lo[1], 0.32), (hi[0], hi[1], 1.0), paint)
    shrink = np.array([0.7, 0.08]) if heading_axis == 0 else np.array([0.08, 0.7])
    back = np.array([0.35, 0.0]) if heading_axis == 0 else np.array([0.0, 0.35])
    clo, chi = lo + shrink + back, hi - shrink + back
    b.box((clo[0], clo[1], 1.0), (chi[0], chi[1], 1.45), {"+x": glass, "-x": glass, "+y": glass, "-y": glass,
                                                          "top": paint})


def street_scene(seed: int = 0) -> Scene:
    """Outdoor T-junction: street A along +y (x in [-5.5, 5.5]) meets street B along +x
    (y in [44.5, 55.5]) at y = 50. Roads at z = 0, sidewalks at z = 0.12 with curbs,
    building facades at 8.5 m from the street centre lines, far end walls at y = 140
    (street A) and x = 215 (street B), parked cars, kiosks and lamp poles; sky."""
    b = SceneBuilder(seed=seed, light_dir=(0.45, -0.35, 0.82), ambient=0.62, diffuse=0.45)
    rng = b.rng
    yA0, yA1 = -40.0, 140.0
    xB1 = 215.0
    # roads (z = 0): street A, then street B east of street A
    b.horizontal(-5.5, yA0, 5.5, yA1, 0.0, ASPHALT)
    b.horizontal(5.5, 44.5, xB1, 55.5, 0.0, ASPHALT)
    # sidewalks (z = 0.12) and curbs, non-overlapping rectangles
    hs = 0.12
    walks = [((-8.5, yA0), (-5.5, yA1), "+x"), ((5.5, yA0), (8.5, 41.5), "-x"), ((5.5, 41.5), (xB1, 44.5), "+y"),
             ((5.5, 58.5), (8.5, yA1), "-x"), ((5.5, 55.5), (xB1, 58.5), "-y")]
    for (x0, y0), (x1, y1), curb in walks:
        b.horizontal(x0, y0, x1, y1, hs, PAVING)
        b.box((x0, y0, 0.0), (x1, y1, hs), CURB, skip=tuple(f for f in ("+x", "-x", "+y", "-y", "top", "bottom")
                                                             if f != curb))
    # lane markings: dashed centre lines, stop line and crossing stripes (5 mm above the road)
    for y in np.arange(yA0 + 2.0, yA1 - 3.0, 9.0):
        if 41.0 < y < 57.0:
            continue
        b.horizontal(-0.075, y, 0.075, y + 3.0, 0.005, PAINT)
    for x in np.arange(12.0, xB1 - 3.0, 9.0):
        b.horizontal(x, 49.925, x + 3.0, 50.075, 0.005, PAINT)
    for x in np.arange(-5.0, 5.2, 1.0):  # zebra crossing before the junction
        b.horizontal(x, 38.5, x + 0.5, 41.0, 0.005, PAINT)
    for y in np.arange(45.0, 55.2, 1.0):  # zebra crossing at the start of street B
        b.horizontal(9.5, y, 12.0, y + 0.5, 0.005, PAINT)
    b.horizontal(0.0, 37.6, 5.4, 38.0, 0.005, PAINT)  # stop line
    # buildings
    _building_row(b, 1, yA0, yA1, -8.5, -1, "+x")                      # west of street A
    _building_row(b, 1, yA0, 29.5, 8.5, +1, "-x")                      # east of A, south of B
    _building(b, (8.5, 29.5, 0.0), (20.5, 41.5, 16.0), ("-x", "+y"))  # south-east corner
    _building_row(b, 0, 20.5, xB1, 41.5, -1, "+y")                     # south of street B
    _building(b, (8.5, 58.5, 0.0), (20.5, 70.5, 19.0), ("-x", "-y"))  # north-east corner
    _building_row(b, 1, 70.5, yA1, 8.5, +1, "-x")                      # east of A, north of B
    _building_row(b, 0, 20.5, xB1, 58.5, +1, "-y")                     # north of street B
    _building(b, (-8.5, yA1, 0.0), (8.5, yA1 + 12.0, 24.0), ("-y",))   # end of street A
    _building(b, (xB1, 41.5, 0.0), (xB1 + 12.0, 58.5, 21.0), ("-x",))  # end of street B
    # parked cars along the curbs (none near the junction)
    for side_x in (4.6, -4.6):
        y = yA0 + rng.uniform(0, 6)
        while y < yA1 - 5:
            if not 30.0 < y < 66.0:
                _car(b, (side_x, y), 1)
            y += rng.uniform(5.5, 14.0)
    for side_y in (45.4, 54.6):
        x = 24.0 + rng.uniform(0, 6)
        while x < xB1 - 5:
            _car(b, (x, side_y), 0)
            x += rng.uniform(5.5, 14.0)
    # kiosks with posters on the sidewalks
    for (cx, cy) in ((-7.2, 12.0), (7.3, 20.0), (35.0, 43.2), (-7.2, 75.0), (60.0, 57.0)):
        lo = np.array([cx - 0.9, cy - 0.9, hs])
        hi = np.array([cx + 0.9, cy + 0.9, hs + 2.5])
        posters = {f: Material(SHOP_PHOTOS[rng.integers(len(SHOP_PHOTOS))]) for f in ("+x", "-x", "+y", "-y")}
        posters["top"] = Material("gravel", tile_m=1.0, tint=(0.3, 0.32, 0.3))
        b.box(lo, hi, posters, fit_faces=("+x", "-x", "+y", "-y"))
    # lamp poles along the curbs
    pole = Material("gravel", tile_m=0.8, tint=(0.35, 0.37, 0.38), contrast=0.8)
    for y in np.arange(yA0 + 5.0, yA1, 16.0):
        for x in (-5.9, 5.9):
            if x > 0 and 40.0 < y < 60.0:
                continue
            b.box((x - 0.08, y - 0.08, hs), (x + 0.08, y + 0.08, 5.5), pole)
    for x in np.arange(20.0, xB1, 16.0):
        for y in (44.1, 55.9):
            b.box((x - 0.08, y - 0.08, hs), (x + 0.08, y + 0.08, 5.5), pole)
    return b.build(sky=True, fog_m=450.0, name="street")


def room_scene(seed: int = 0) -> Scene:
    """Indoor room x in [0, 6], y in [0, 5], z in [0, 3] m: textured floor, walls and
    ceiling, posters, a window, a door, a rug, a table, a sofa, a tall cabinet with a whiteboard
    front, a metal cabinet and
    cardboard boxes. All rays hit something (no invalid depth)."""
    b = SceneBuilder(seed=seed, light_dir=(0.25, 0.35, 1.0), ambient=0.8, diffuse=0.3)
    rng = b.rng
    W, D, H = 6.0, 5.0, 3.0
    floor = Material("gravel", tile_m=1.2, tint=(0.72, 0.55, 0.4), macro="clouds", macro_tile_m=4.0,
                     macro_strength=0.3)
    wall = Material("gravel", tile_m=0.9, tint=(1.35, 1.28, 1.12), contrast=0.4, macro="clouds", macro_tile_m=3.0,
                    macro_strength=0.3)
    wall2 = Material("brick", tile_m=1.8, tint=(0.8, 0.55, 0.45), macro="clouds", macro_tile_m=5.0,
                     macro_strength=0.2)
    ceiling = Material("gravel", tile_m=1.5, tint=(1.45, 1.45, 1.4), contrast=0.35)
    b.horizontal(0, 0, W, D, 0.0, floor)                    # floor, seen from above
    b.horizontal(0, 0, W, D, H, ceiling, up=False)          # ceiling, seen from below
    b.wall((W, 0), (0, 0), 0.0, H, wall)                    # y = 0 wall, seen from +y
    b.wall((0, D), (W, D), 0.0, H, wall)                    # y = D wall, seen from -y
    b.wall((0, 0), (0, D), 0.0, H, wall2)                   # x = 0 wall, seen from +x
    b.wall((W, D), (W, 0), 0.0, H, wall)                    # x = W wall, seen from -x
    down = np.array([0.0, 0.0, -1.0])
    walls = {  # left corner seen from inside the room, right direction, length
        "y0": ((W, 0.0), (-1.0, 0.0), W), "yD": ((0.0, D), (1.0, 0.0), W),
        "x0": ((0.0, 0.0), (0.0, 1.0), D), "xW": ((W, D), (0.0, -1.0), D),
    }
    photos = ["astronaut", "chelsea", "coffee", "rocket", "hubble", "cat", "clock", "retina", "ihc", "camera",
              "text", "coins"]
    order = rng.permutation(len(photos))
    k = 0
    for key, (o, d, length) in walls.items():
        o = np.array([o[0], o[1], 0.0])
        d = np.array([d[0], d[1], 0.0])
        x = rng.uniform(0.3, 0.7)
        while True:
            w = rng.uniform(0.6, 1.3)
            if x + w > length - 0.3:
                break
            h = w * rng.uniform(0.6, 1.2)
            zc = rng.uniform(1.3, 2.1)
            photo = photos[order[k % len(photos)]]
            k += 1
            b.decal(o + (x + w / 2) * d + np.array([0, 0, zc]), d, down, w, h, Material(photo), lift=0.005)
            x += w + rng.uniform(0.25, 0.8)
    # window (x = W wall) and door (y = 0 wall)
    b.decal((W, 1.6, 1.6), (0, -1, 0), down, 1.2, 1.3, Material("hubble", tint=(0.8, 0.9, 1.1)), lift=0.01)
    b.decal((4.6, 0.0, 1.02), (-1, 0, 0), down, 0.9, 2.02, Material("brick", tile_m=1.0, tint=(0.55, 0.38, 0.25)),
            lift=0.01, fit=False)
    b.decal((2.6, 2.2, 0.0), (1, 0, 0), (0, -1, 0), 2.2, 1.6, Material("ihc", tint=(0.95, 0.9, 0.9)), lift=0.004)
    # furniture
    wood = Material("brick", tile_m=1.2, tint=(0.6, 0.42, 0.28), contrast=0.8)
    fabric = Material("grass", tile_m=1.0, tint=(0.35, 0.45, 0.7))
    board = Material("text", tint=(0.95, 0.95, 0.92))
    cardboard = Material("gravel", tile_m=0.6, tint=(0.78, 0.6, 0.4))
    metal = Material("coins", tile_m=0.8, tint=(0.7, 0.72, 0.75))
    b.box((2.0, 1.9, 0.70), (3.6, 2.8, 0.76), {f: wood for f in ("+x", "-x", "+y", "-y", "top", "bottom")}, skip=())
    for lx, ly in ((2.05, 1.95), (3.5, 1.95), (2.05, 2.7), (3.5, 2.7)):
        b.box((lx, ly, 0.0), (lx + 0.05, ly + 0.05, 0.70), wood)
    b.box((0.15, 3.2, 0.0), (1.1, 4.9, 0.45), fabric)           # sofa seat
    b.box((0.05, 3.2, 0.0), (0.15, 4.9, 0.9), fabric)           # sofa back
    b.box((2.2, 4.6, 0.0), (4.4, 4.95, 2.0), {"-y": board, "+x": wood, "-x": wood, "top": wood, "+y": wood},
          fit_faces=("-y",))
    b.box((5.4, 3.4, 0.0), (5.95, 4.5, 1.8), metal)
    b.box((4.6, 0.3, 0.0), (5.2, 0.8, 0.45), cardboard)
    b.box((4.7, 0.4, 0.45), (5.1, 0.75, 0.75), cardboard)
    b.box((0.6, 0.3, 0.0), (1.3, 0.9, 0.55), cardboard)
    return b.build(sky=False, fog_m=0.0, name="room")


def tiny_scene(seed: int = 0) -> Scene:
    """A few textured quads in front of the origin (for tests): a floor at z = 0, a back
    wall at y = 6, a side wall at x = -2 and a box; cameras near (0, 0, 1) looking +y see it."""
    b = SceneBuilder(seed=seed, texture_size=128)
    b.horizontal(-4, -2, 4, 8, 0.0, Material("gravel", tile_m=1.0))
    b.quad((-4, 6, 3), (8, 0, 0), (0, 0, -3), Material("brick", tile_m=1.5, tint=(0.9, 0.5, 0.4)))
    b.wall((-2, -2), (-2, 8), 0.0, 3.0, Material("grass", tile_m=1.0, tint=(0.5, 0.8, 0.5)))
    b.box((0.3, 3.0, 0.0), (1.3, 3.8, 1.2), Material("coins", tile_m=0.7))
    b.decal((-0.5, 6.0, 1.6), (1, 0, 0), (0, 0, -1), 1.6, 1.2, Material("chelsea"), lift=0.01)
    return b.build(sky=True, name="tiny")


_SCENES = {"street": street_scene, "room": room_scene, "tiny": tiny_scene}


def scene_names() -> list[str]:
    return sorted(_SCENES)


def build_scene(name: str, seed: int = 0) -> Scene:
    """Scene ``name`` ("street", "room" or "tiny") built with ``seed``.

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
    """
    return lookup("scene", name, _SCENES)(seed)
