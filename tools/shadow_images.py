"""The two images of docs/rendering.md, "Soft shadows on Manhattan and Euclidean fields": one scene
(a floor, a sphere, a box turned 45 degrees and a thin pillar) rendered with soft shadows and no
ambient occlusion in a Manhattan and in a Euclidean world, so the penumbrae alone differ.

    python3 tools/shadow_images.py                    # writes docs/images/shadows-{manhattan,euclidean}.png
    python3 tools/shadow_images.py --device pocl      # a device spec, as `sdfserver serve --device`

The images in docs/ were made on a CPU OpenCL device (Intel's runtime); another device draws the
same frames up to float rounding. Prints how many pixels differ and by how much.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from sdfserver.gpu import GpuContext
from sdfserver.render import Camera, RenderOptions, Renderer, encode_frame
from sdfserver.world import World, WorldConfig

SIZE = 64
OUT = Path(__file__).resolve().parents[1] / "docs" / "images"


def scene() -> np.ndarray:
    z, y, x = np.mgrid[:SIZE, :SIZE, :SIZE]
    voxels = np.zeros((SIZE, SIZE, SIZE), np.uint8)
    voxels[y < 3] = 0b101_101_10  # a grey floor
    voxels[(x - 40) ** 2 + (y - 14) ** 2 + (z - 22) ** 2 <= 100] = 0b111_001_00
    # A box turned 45 degrees about y: its shadow's edges run diagonally across the floor.
    voxels[(np.abs(x - 18) + np.abs(z - 40) <= 10) & (y >= 3) & (y < 20)] = 0b001_011_11
    voxels[(x >= 50) & (x < 52) & (z >= 46) & (z < 48) & (y < 40)] = 0b111_110_00  # a thin pillar
    return voxels


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="OpenCL device spec (default: the first usable)")
    parser.add_argument("--width", type=int, default=360)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    gpu = GpuContext.create(args.device)
    renderer = Renderer(gpu)
    camera = Camera.look_at((78.0, 52.0, 92.0), (30.0, 6.0, 30.0), fov_y_deg=50.0,
                            width=args.width, height=args.height).validated()
    options = RenderOptions(shadows=True, light=(-0.55, 0.6, -0.35))
    pixels = {}
    for metric in ("manhattan", "euclidean"):
        world = World(gpu, WorldConfig((SIZE, SIZE, SIZE), 16, 255, metric=metric))
        world.load_voxels(scene())
        world.recompute()
        pixels[metric] = renderer.render(world, camera, options).pixels
        args.out.mkdir(parents=True, exist_ok=True)
        path = args.out / f"shadows-{metric}.png"
        path.write_bytes(encode_frame(pixels[metric], "png"))
        print(f"{path} ({path.stat().st_size} bytes)")
        world.release()
    diff = pixels["euclidean"][..., :3].astype(int).sum(-1) - pixels["manhattan"][..., :3].astype(int).sum(-1)
    print(f"{gpu.device_name}: {(diff < -3).sum()} pixels darker and {(diff > 3).sum()} lighter on the Euclidean "
          f"field, of {diff.size}; mean {diff.mean():.2f} (sum of RGB)")
    renderer.release()


if __name__ == "__main__":
    main()
