"""Procedural textures in numpy: façades, asphalt, pavement, grass, foliage, bark, regolith and rock.

Every generator takes a ``numpy.random.Generator`` and returns an 8-bit RGB image (H, W, 3), row 0 at the
top of the surface as seen upright; :func:`png_asset` flips it for MuJoCo, whose 2-D texture coordinate v
grows upwards. Noise is value noise summed over octaves (several scales, as real surfaces have); a tileable
variant wraps at the image border so that repeated tiles (ground, regolith) show no seams. No builtin
checkers: the point is that what a network learns from these images carries over to real ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

Image = NDArray[np.uint8]
Field = NDArray[np.float32]


def value_noise(rng: np.random.Generator, height: int, width: int, cell: float, tileable: bool = False) -> Field:
    """Smooth noise in about [-1, 1] with features of ``cell`` pixels: a random grid, bicubically enlarged."""
    cell = max(float(cell), 1.0)
    gh, gw = max(round(height / cell), 1), max(round(width / cell), 1)
    grid = rng.uniform(-1.0, 1.0, (gh, gw)).astype(np.float32)
    if tileable:
        pad = 2
        wrapped = np.pad(grid, pad, mode="wrap")
        big = cv2.resize(wrapped, ((gw + 2 * pad) * width // gw, (gh + 2 * pad) * height // gh), interpolation=cv2.INTER_CUBIC)
        y0, x0 = pad * height // gh, pad * width // gw
        return big[y0 : y0 + height, x0 : x0 + width]
    return cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)


def fractal_noise(
    rng: np.random.Generator, height: int, width: int, cells: tuple[float, ...], gain: float = 0.55, tileable: bool = False
) -> Field:
    """Octaves of value noise, coarsest first, each ``gain`` times the previous amplitude; normalised to [-1, 1]."""
    total = np.zeros((height, width), np.float32)
    amplitude = 1.0
    for cell in cells:
        total += amplitude * value_noise(rng, height, width, cell, tileable)
        amplitude *= gain
    peak = float(np.abs(total).max())
    return total / peak if peak > 0 else total


def _colour(base: NDArray[np.float64], shade: Field) -> Image:
    """An RGB image from a base colour (0-1) modulated by ``shade`` (1 = the base colour)."""
    rgb = shade[:, :, None] * np.asarray(base, np.float32)[None, None, :]
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def png_asset(image: Image) -> bytes:
    """PNG bytes for a MuJoCo texture asset (flipped: MuJoCo's v axis points up)."""
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[::-1, :, ::-1]))
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


# --- façades --------------------------------------------------------------------------------------

FACADE_MATERIALS = ("brick", "plaster", "concrete")


@dataclass(frozen=True)
class FacadeLayout:
    """A façade's grid: ``bays`` window columns of ``bay_width`` m and ``storeys`` of ``storey_height`` m
    above a ground floor of ``ground_height`` m, drawn at ``pixels_per_metre``."""

    bays: int
    storeys: int
    bay_width: float = 3.2
    storey_height: float = 3.0
    ground_height: float = 3.6
    pixels_per_metre: float = 16.0

    @property
    def width_m(self) -> float:
        return self.bays * self.bay_width

    @property
    def height_m(self) -> float:
        return self.ground_height + self.storeys * self.storey_height


def _wall(rng: np.random.Generator, material: str, height: int, width: int, ppm: float, palette: NDArray[np.float64]) -> Field:
    """Per-pixel RGB (0-1 floats) of a bare wall of the given material."""
    if material == "brick":
        brick_h, brick_w = max(round(0.075 * ppm * 2), 2), max(round(0.24 * ppm * 2), 4)
        rows = np.arange(height) // brick_h
        offset = (rows % 2) * (brick_w // 2)
        cols = (np.arange(width)[None, :] + offset[:, None]) // brick_w
        ids = rows[:, None] * 1000 + cols
        jitter = rng.normal(0.0, 0.09, (int(ids.max()) + 1,)).astype(np.float32)
        shade = 1.0 + jitter[ids]
        mortar = ((np.arange(height) % brick_h) == 0)[:, None] | (((np.arange(width)[None, :] + offset[:, None]) % brick_w) == 0)
        shade = np.where(mortar, 1.35, shade)
    elif material == "plaster":
        shade = 1.0 + 0.06 * fractal_noise(rng, height, width, (ppm * 3, ppm, ppm / 3, 2.0))
    else:  # concrete panels
        panel = max(round(1.5 * ppm), 4)
        shade = 1.0 + 0.05 * fractal_noise(rng, height, width, (ppm * 2, ppm / 2, 2.0))
        joints = ((np.arange(height) % (2 * panel)) < 1)[:, None] | ((np.arange(width) % (3 * panel)) < 1)[None, :]
        shade = np.where(joints, 0.7, shade)
    # weathering: darker streaks running down from the top, brighter patches
    streaks = value_noise(rng, height, width, ppm * 0.6)
    streaks = cv2.resize(streaks[:1], (width, height), interpolation=cv2.INTER_LINEAR) * 0.5 + 0.5 * streaks
    shade = shade * (1.0 - 0.08 * np.clip(streaks, 0, 1) * np.linspace(1.0, 0.3, height, dtype=np.float32)[:, None])
    return shade[:, :, None].astype(np.float32) * palette[None, None, :].astype(np.float32)


def facade(rng: np.random.Generator, layout: FacadeLayout, material: str | None = None) -> Image:
    """A whole façade: wall material, storeys of framed windows (glass reflecting a sky gradient, blinds at
    random heights, sills), a ground floor with doors and shop windows, a cornice line per storey."""
    ppm = layout.pixels_per_metre
    width, height = round(layout.width_m * ppm), round(layout.height_m * ppm)
    material = material or FACADE_MATERIALS[int(rng.integers(len(FACADE_MATERIALS)))]
    palettes = {
        "brick": ((0.55, 0.30, 0.22), (0.62, 0.42, 0.30), (0.45, 0.28, 0.24), (0.66, 0.55, 0.45)),
        "plaster": ((0.86, 0.82, 0.72), (0.80, 0.75, 0.62), (0.72, 0.76, 0.78), (0.90, 0.88, 0.84), (0.78, 0.62, 0.48)),
        "concrete": ((0.62, 0.62, 0.60), (0.55, 0.56, 0.57), (0.70, 0.68, 0.64)),
    }
    choices = palettes[material]
    palette = np.array(choices[int(rng.integers(len(choices)))]) * rng.uniform(0.85, 1.1)
    rgb = _wall(rng, material, height, width, ppm, palette)
    frame_colour = np.array((0.92, 0.92, 0.9) if rng.random() < 0.6 else (0.25, 0.22, 0.2), np.float32)
    glass_top = np.array((0.45, 0.52, 0.6), np.float32) * rng.uniform(0.6, 1.1)
    glass_bottom = np.array((0.12, 0.13, 0.15), np.float32)
    win_w = rng.uniform(0.9, 1.6) * ppm
    win_h = rng.uniform(1.3, 1.8) * ppm
    frame = max(round(0.08 * ppm), 1)

    def window(x0: int, y0: int, w: int, h: int, blinds: bool = True) -> None:
        x1, y1 = min(x0 + w, width), min(y0 + h, height)
        if x1 - x0 < 3 or y1 - y0 < 3:
            return
        rgb[y0:y1, x0:x1] = frame_colour
        gy = np.linspace(0.0, 1.0, y1 - y0 - 2 * frame, dtype=np.float32)[:, None, None]
        glass = (1 - gy) * glass_top + gy * glass_bottom
        glass = glass * (1.0 + 0.15 * value_noise(rng, y1 - y0 - 2 * frame, x1 - x0 - 2 * frame, ppm)[:, :, None])
        rgb[y0 + frame : y1 - frame, x0 + frame : x1 - frame] = glass
        if blinds and rng.random() < 0.4:  # a blind or curtain pulled part way down
            drop = int(rng.uniform(0.1, 0.8) * (y1 - y0 - 2 * frame))
            tone = np.float32(rng.uniform(0.55, 0.9))
            rgb[y0 + frame : y0 + frame + drop, x0 + frame : x1 - frame] = tone
        mid = (x0 + x1) // 2
        rgb[y0:y1, mid : mid + frame] = frame_colour  # mullion
        sill_y = min(y1, height - 1)
        rgb[sill_y : sill_y + frame + 1, max(x0 - frame, 0) : min(x1 + frame, width)] = frame_colour * 0.85

    bay_px = layout.bay_width * ppm
    ground_px = layout.ground_height * ppm
    storey_px = layout.storey_height * ppm
    for storey in range(layout.storeys):
        top = round(height - ground_px - (storey + 1) * storey_px)
        cornice = max(top + int(storey_px) - frame, 0)
        rgb[cornice : cornice + frame, :] *= 0.8
        for bay in range(layout.bays):
            x0 = round(bay * bay_px + (bay_px - win_w) / 2)
            y0 = round(top + 0.3 * storey_px)
            window(x0, y0, int(win_w), int(win_h))
    # ground floor: a door in one bay, shop windows or plain windows in the others
    door_bay = int(rng.integers(layout.bays))
    base = round(height - ground_px)
    shops = rng.random() < 0.5
    for bay in range(layout.bays):
        if bay == door_bay:
            door_w, door_h = int(1.1 * ppm), int(2.3 * ppm)
            x0 = round(bay * bay_px + (bay_px - door_w) / 2)
            y0 = height - door_h
            rgb[y0:height, x0 : x0 + door_w] = frame_colour * 0.9
            rgb[y0 + frame : height, x0 + frame : x0 + door_w - frame] = np.float32(rng.uniform(0.15, 0.45)) * palette
        elif shops:
            window(
                int(bay * bay_px + 0.2 * ppm), base + int(0.5 * ppm), int(bay_px - 0.4 * ppm), int(ground_px - 0.6 * ppm), False
            )
        else:
            x0 = round(bay * bay_px + (bay_px - win_w) / 2)
            window(x0, base + int(0.8 * ppm), int(win_w), int(win_h))
    # a plinth, darker at the foot of the wall
    plinth = int(0.4 * ppm)
    rgb[height - plinth :, :] *= 0.7
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


# --- ground surfaces ------------------------------------------------------------------------------


def asphalt(rng: np.random.Generator, along: float = 8.0, across: float = 8.0, ppm: float = 64.0, lanes: bool = True) -> Image:
    """Road surface ``along`` x ``across`` m (image x: along the road, y: across, the centre line in the middle):
    aggregate speckle at several scales, wheel-track wear, patches, cracks; a dashed centre line (3 m dashes
    every 6.4 m) and solid lines 3.5 m either side of it."""
    width, height = round(along * ppm), round(across * ppm)
    grey = rng.uniform(0.26, 0.40)
    shade = 1.0 + 0.10 * fractal_noise(rng, height, width, (ppm * 4, ppm, ppm / 4))
    shade += 0.12 * rng.standard_normal((height, width)).astype(np.float32)  # aggregate grains
    offset = (np.arange(height, dtype=np.float32) + 0.5) / ppm - across / 2  # metres from the centre line
    for track in (-2.6, -0.9, 0.9, 2.6):  # wheel tracks: polished, slightly darker
        shade -= 0.06 * np.exp(-0.5 * ((offset - track) / 0.35) ** 2)[:, None]
    for _ in range(int(rng.poisson(0.6 * along * across / 64))):  # patched repairs, darker and smoother
        h, w = (rng.uniform(0.6, 2.5, 2) * ppm).astype(int)
        y, x = rng.integers(0, max(height - h, 1)), rng.integers(0, max(width - w, 1))
        shade[y : y + h, x : x + w] = shade[y : y + h, x : x + w] * 0.6 + 0.3 * np.float32(rng.uniform(0.7, 0.95))
    image = np.clip(shade * grey, 0, 1)
    for _ in range(int(rng.poisson(1.5 * along * across / 64))):  # cracks: random walks
        point = rng.uniform(0, 1, 2) * (width, height)
        steps = np.cumsum(rng.normal(0, ppm * 0.08, (40, 2)) + rng.normal(0, ppm * 0.05, 2), axis=0) + point
        cv2.polylines(image, [steps.astype(np.int32).reshape(-1, 1, 2)], False, float(grey * 0.45), 1, cv2.LINE_AA)
    if lanes:
        paint = np.float32(rng.uniform(0.7, 0.85))
        line = max(int(0.12 * ppm), 2)
        centre = height // 2
        dash = np.arange(width) / ppm % 6.4 < 3.0
        image[centre - line // 2 : centre + line - line // 2, dash] = paint
        for edge in (-1, 1):
            row = int(centre + edge * 3.5 * ppm)
            if 0 <= row - line // 2 and row + line < height:
                image[row - line // 2 : row + line - line // 2, :] = paint
        wear = value_noise(rng, height, width, ppm * 0.3)
        image = np.where(image > grey * 1.6, image * (0.8 + 0.2 * np.clip(wear + 0.5, 0, 1)), image)
    tint = np.array((1.0, 1.0, 1.03))
    return np.clip(image[:, :, None] * tint * 255 + 0.5, 0, 255).astype(np.uint8)


def pavement(rng: np.random.Generator, size: int = 256, metres: float = 4.0) -> Image:
    """Concrete slabs or small pavers with joints, colour variation per slab and grime."""
    ppm = size / metres
    slab = int(ppm * (rng.uniform(0.2, 0.3) if rng.random() < 0.5 else rng.uniform(0.5, 1.0)))
    slab = max(slab, 4)
    rows, cols = np.arange(size) // slab, np.arange(size) // slab
    ids = rows[:, None] * 997 + cols[None, :]
    jitter = rng.normal(0, 0.05, int(ids.max()) + 1).astype(np.float32)
    shade = 1.0 + jitter[ids] + 0.06 * fractal_noise(rng, size, size, (ppm, ppm / 4, 2.0), tileable=True)
    joints = ((np.arange(size) % slab) == 0)[:, None] | ((np.arange(size) % slab) == 0)[None, :]
    shade = np.where(joints, 0.65, shade)
    base = np.array((0.62, 0.60, 0.57)) * rng.uniform(0.85, 1.1)
    return _colour(base, shade)


def grass(rng: np.random.Generator, size: int = 256, metres: float = 4.0) -> Image:
    """Grass and soil: fine blade noise over patchy green-brown colour."""
    ppm = size / metres
    patches = fractal_noise(rng, size, size, (ppm * 2, ppm / 2), tileable=True)
    blades = rng.standard_normal((size, size)).astype(np.float32)
    blades = cv2.GaussianBlur(blades, (0, 0), 0.7) * 1.8
    green = np.array((0.30, 0.40, 0.17)) * rng.uniform(0.8, 1.2)
    brown = np.array((0.42, 0.37, 0.26))
    mix = np.clip(0.5 + 0.6 * patches, 0, 1)[:, :, None]
    rgb = mix * green + (1 - mix) * brown
    rgb = rgb * (1.0 + 0.25 * blades[:, :, None])
    return np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)


def foliage(rng: np.random.Generator, size: int = 128) -> Image:
    """Leaves: dark gaps and bright clusters at two scales."""
    clusters = fractal_noise(rng, size, size, (size / 6, size / 20, 2.0), gain=0.8, tileable=True)
    shade = np.clip(0.85 + 0.6 * clusters, 0.15, 1.6)
    base = np.array((0.20, 0.33, 0.12)) * rng.uniform(0.7, 1.3)
    return _colour(base, shade)


def bark(rng: np.random.Generator, size: int = 64) -> Image:
    """Bark: vertical furrows."""
    furrows = value_noise(rng, size, size, 3.0, tileable=True)
    furrows = cv2.resize(furrows[:4], (size, size), interpolation=cv2.INTER_CUBIC) + 0.3 * furrows
    return _colour(np.array((0.33, 0.27, 0.21)), 1.0 + 0.4 * furrows)


def regolith(rng: np.random.Generator, size: int = 512, metres: float = 8.0, density: float = 900.0) -> Image:
    """Rover-site ground: soil at several scales strewn with ``density`` stones per m² of many sizes, each
    lit from one side (a texture cannot cast shadows, but its shading reads as relief to a tracker)."""
    ppm = size / metres
    base = np.array((0.42, 0.38, 0.33)) * rng.uniform(0.75, 1.2)
    shade = 1.0 + 0.18 * fractal_noise(rng, size, size, (ppm * 3, ppm, ppm / 4, 2.0), tileable=True)
    shade += 0.15 * rng.standard_normal((size, size)).astype(np.float32)
    image = shade.copy()
    # stones: a power law of sizes (many small, few large), 8-100 mm, as angular polygons with a sunlit
    # face, a darker flank and a cast shadow on the far side
    count = int(rng.uniform(0.7, 1.3) * density * metres * metres)
    radii = np.clip(0.008 * (1.0 - rng.random(count)) ** (-1 / 1.4), 0.008, 0.10) * ppm
    centres = rng.uniform(0, size, (count, 2))
    tones = rng.uniform(0.6, 2.6, count).astype(np.float32)
    small = radii < 1.2
    image[centres[small, 1].astype(int) % size, centres[small, 0].astype(int) % size] = tones[small]
    large = np.flatnonzero(~small)
    shadow = np.array([0.35, 0.25])  # the shadow falls to the lower right of each stone
    for i in large[np.argsort(-radii[large])]:  # big first, smaller ones on top
        r = float(radii[i])
        corners = int(rng.integers(4, 8))
        angles = np.sort(rng.uniform(0, 2 * np.pi, corners))
        outline = centres[i] + np.column_stack([np.cos(angles), np.sin(angles)]) * r * rng.uniform(0.6, 1.2, (corners, 1))
        cv2.fillConvexPoly(image, np.round(outline + shadow * r).astype(np.int32), float(tones[i] * 0.25), cv2.LINE_AA)
        cv2.fillConvexPoly(image, np.round(outline).astype(np.int32), float(tones[i] * 0.6), cv2.LINE_AA)
        lit = centres[i] + (outline - centres[i]) * 0.7 - 0.2 * r
        cv2.fillConvexPoly(image, np.round(lit).astype(np.int32), float(tones[i]), cv2.LINE_AA)
    return _colour(base, image)


def rock(rng: np.random.Generator, size: int = 128) -> Image:
    """Rock surface: mottled, with veins and lichen-like spots."""
    shade = 1.0 + 0.25 * fractal_noise(rng, size, size, (size / 4, size / 16, 2.0), tileable=True)
    veins = np.abs(value_noise(rng, size, size, size / 8, tileable=True)) < 0.02
    shade = np.where(veins, shade * 0.8, shade)
    shade += 0.12 * rng.standard_normal((size, size)).astype(np.float32)  # grain
    base = np.array((0.50, 0.46, 0.42)) * rng.uniform(0.7, 1.2)
    return _colour(base, shade)
