"""report.html's scene GLB, read back byte by byte: the mesh is unlit, its COLOR_0 holds the std colours in
glTF's linear space with the baked shade in the alpha, and the cameras' frustums ride along as lines."""

import json
import struct

import numpy as np
import trimesh

from ushape.reconstruction.report_page import LIGHT, Scene, baked_shade, scene_glb, srgb_to_linear


def read_glb(data: bytes) -> tuple[dict, bytes]:
    magic, version, length = struct.unpack("<III", data[:12])
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    json_length = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20 : 20 + json_length]), data[20 + json_length + 8 :]


def accessor(gltf: dict, blob: bytes, index: int, dtype, width: int) -> np.ndarray:
    view = gltf["bufferViews"][gltf["accessors"][index]["bufferView"]]
    raw = np.frombuffer(blob[view["byteOffset"] : view["byteOffset"] + view["byteLength"]], dtype)
    return raw.reshape(-1, width)


def test_srgb_to_linear_known_values():
    # The sRGB transfer function's ends, its linear toe and a mid value (0.5 -> 0.2140).
    got = srgb_to_linear(np.array([0.0, 0.04045, 0.5, 1.0]))
    np.testing.assert_allclose(got, [0.0, 0.04045 / 12.92, 0.21404, 1.0], atol=1e-5)


def test_the_shade_is_half_lambert_under_the_fixed_light():
    side = np.cross(LIGHT, [0.0, 0.0, 1.0])
    normals = np.stack([LIGHT, -LIGHT, side / np.linalg.norm(side)])
    np.testing.assert_allclose(baked_shade(normals), [1.0, 0.0, 0.25], atol=1e-12)


def test_the_scene_is_one_unlit_glb_with_linear_colours_and_the_shade_in_alpha():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    srgb = np.zeros((len(mesh.vertices), 4), np.uint8)
    srgb[:, 0], srgb[:, 1], srgb[:, 2], srgb[:, 3] = 255, 128, np.arange(len(mesh.vertices)) % 256, 255
    mesh.visual.vertex_colors = srgb
    K = np.array([[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]])
    w2c = np.eye(4)
    w2c[2, 3] = 3.0
    gltf, blob = read_glb(scene_glb(Scene("one", mesh, cameras=[(K, w2c, (64, 64))])))
    assert gltf["extensionsUsed"] == ["KHR_materials_unlit"]
    assert gltf["materials"][0]["extensions"] == {"KHR_materials_unlit": {}}
    triangles, lines = gltf["meshes"][0]["primitives"]
    assert (triangles["mode"], lines["mode"], triangles["material"]) == (4, 1, 0)
    colours = accessor(gltf, blob, triangles["attributes"]["COLOR_0"], np.uint8, 4)
    expected = np.round(srgb_to_linear(srgb[:, :3] / 255.0) * 255)
    np.testing.assert_array_equal(colours[:, :3], expected)  # integers from one rounding of the same numbers
    shade = colours[:, 3] / 255.0
    np.testing.assert_allclose(shade, baked_shade(mesh.vertex_normals), atol=0.5 / 255 + 1e-9)
    assert shade.max() > 0.95 and shade.min() < 0.05  # a sphere faces the light and turns away from it
    positions = accessor(gltf, blob, triangles["attributes"]["POSITION"], np.float32, 3)
    np.testing.assert_allclose(positions, mesh.vertices, atol=1e-6)
    assert accessor(gltf, blob, lines["attributes"]["POSITION"], np.float32, 3).shape == (
        8 * 2,
        3,
    )  # 8 segments of the frustum
