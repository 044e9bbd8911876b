"""Levels of detail: far terrain tiles drawn coarse, without cracks where they meet fine ones."""

from __future__ import annotations

import os

import numpy as np
import pytest
from pvo_sim.presets.planetary import LOD_STEP, TILE_SAMPLES, _on_coarse_lines
from pvo_sim.render import RangeCuller, SimConfig, camera_trajectory
from pvo_sim.world import LOD_FAR_GROUP, LOD_NEAR_GROUP, WorldSpec, build_world

os.environ.setdefault("MUJOCO_GL", "egl")  # before anything imports mujoco


def test_samples_between_coarse_ones_move_onto_the_coarse_line() -> None:
    line = np.random.default_rng(0).random(2 * LOD_STEP * 5 + 1)
    out = _on_coarse_lines(line)
    coarse = np.arange(0, len(line), LOD_STEP)
    assert np.array_equal(out[coarse], line[coarse])
    between = np.setdiff1d(np.arange(len(line)), coarse)
    assert np.allclose(out[between], np.interp(between, coarse, line[coarse]))
    ragged = np.random.default_rng(1).random(LOD_STEP * 4 + 2)  # a partial last stretch stays as it was
    kept = _on_coarse_lines(ragged)
    assert np.array_equal(kept[LOD_STEP * 4 :], ragged[LOD_STEP * 4 :])


def _planetary_world():
    config = SimConfig(preset="planetary", frames=120, path="straight", speed=2.0, seed=4)
    poses = camera_trajectory(config)
    spec = WorldSpec("planetary", config.seed, config.baseline, 40.0, False, image_size=(config.width, config.height))
    return build_world(spec, poses, config.camera_height)


def test_far_tiles_are_the_fine_ones_subsampled_and_edges_match() -> None:
    world = _planetary_world()
    fine = {name: h for name, h in world.hfields.items() if not name.endswith("_far")}
    far = {name[: -len("_far")]: h for name, h in world.hfields.items() if name.endswith("_far")}
    assert far, "no full tile got a coarse twin"
    for name, coarse in far.items():
        tile = fine[name]
        assert tile.shape == (TILE_SAMPLES + 1, TILE_SAMPLES + 1)
        assert np.array_equal(coarse, tile[::LOD_STEP, ::LOD_STEP])
        # a fine tile's border, read at its own resolution, is the coarse border interpolated: no crack
        borders = ((tile[0], coarse[0]), (tile[-1], coarse[-1]), (tile[:, 0], coarse[:, 0]), (tile[:, -1], coarse[:, -1]))
        for border, coarse_border in borders:
            positions = np.arange(len(border))
            assert np.allclose(border, np.interp(positions, positions[::LOD_STEP], coarse_border), atol=1e-12)
    groups = {f'hfield="{name}"': LOD_NEAR_GROUP for name in far} | {f'hfield="{name}_far"': LOD_FAR_GROUP for name in far}
    for line in world.xml.splitlines():
        for key, group in groups.items():
            if key + " " in line:
                assert f'group="{group}"' in line


def test_the_culler_draws_fine_near_and_coarse_far() -> None:
    mujoco = pytest.importorskip("mujoco")
    xml = f"""<mujoco><worldbody>
      <geom name="near_fine" type="sphere" size="1" pos="5 0 0" group="{LOD_NEAR_GROUP}"/>
      <geom name="near_coarse" type="sphere" size="1" pos="5 0 0" group="{LOD_FAR_GROUP}"/>
      <geom name="far_fine" type="sphere" size="1" pos="60 0 0" group="{LOD_NEAR_GROUP}"/>
      <geom name="far_coarse" type="sphere" size="1" pos="60 0 0" group="{LOD_FAR_GROUP}"/>
      <geom name="plain" type="sphere" size="1" pos="60 0 0"/>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    cull = RangeCuller(model, detail=20.0)
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical z along world +x
    option = cull(data, pose)
    shown = {model.geom(i).name for i in range(model.ngeom) if option.geomgroup[model.geom_group[i]]}
    assert shown == {"near_fine", "far_coarse", "plain"}
