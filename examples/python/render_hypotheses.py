#!/usr/bin/env python3
"""Render pose hypotheses of a model with perch2.Renderer and show them with matplotlib (optional).

    python examples/python/render_hypotheses.py [--model MESH.ply --scale 0.001] [--out hypotheses.png]

Renders a grid of hypotheses (turns about the camera's y axis, at 0.6 m) into one CloudBatch (numpy arrays,
no copy) and draws each hypothesis' depth image. Without --model it renders a built-in box. Without
matplotlib it prints the per-hypothesis point counts and skips the plot.
"""

import argparse

import numpy as np

import perch2


def box_mesh():
    h = 0.05
    v = np.array([[x, y, z] for z in (-h, h) for y in (-h, h) for x in (-2 * h, 2 * h)])
    f = [[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
         [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]]
    colors = (np.abs(v) > 0).astype(np.uint8) * np.array([[200, 120, 40]], np.uint8)
    return perch2.Mesh(v, f, colors=colors, name="box")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", help="a PLY or OBJ mesh (default: a box)")
    ap.add_argument("--scale", type=float, default=1.0, help="file units -> metres (BOP PLY: 0.001)")
    ap.add_argument("--out", help="save the figure here instead of showing it")
    ap.add_argument("--backend", default="thrust_omp")
    a = ap.parse_args()
    mesh = perch2.load_mesh(a.model, scale=a.scale) if a.model else box_mesh()

    camera = perch2.Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
    poses = []
    for k in range(8):  # turns about the camera's y axis and a tilt, 0.6 m in front of the camera
        yaw, tilt = k * np.pi / 4, 0.4
        Ry = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        Rx = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rx @ Ry, (0.0, 0.0, 0.6)
        poses.append(T)
    settings = perch2.RenderSettings()
    settings.stride = 2
    clouds = perch2.Renderer([mesh], backend=a.backend).render(0, np.stack(poses), camera, settings)
    counts = np.diff(clouds.offsets)
    print(f"{clouds.num_clouds()} hypotheses, {len(clouds)} points: {counts.tolist()}")

    try:
        import matplotlib

        if a.out:
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: plot skipped (pip install matplotlib)")
        return
    grid = camera.at_stride(settings.stride)
    fig, axes = plt.subplots(2, 4, figsize=(12, 5))
    for h, ax in enumerate(axes.ravel()):
        a0, a1 = clouds.offsets[h], clouds.offsets[h + 1]
        img = np.full((grid.height, grid.width), np.nan)
        px = clouds.pixel[a0:a1]
        img[px // camera.width // settings.stride, px % camera.width // settings.stride] = clouds.z[a0:a1]
        ax.imshow(img, cmap="viridis")
        ax.set_title(f"hypothesis {h}: {a1 - a0} points")
        ax.axis("off")
    fig.tight_layout()
    if a.out:
        fig.savefig(a.out)
        print(f"figure -> {a.out}")
    else:
        plt.show()


if __name__ == "__main__":
    main()
