"""``reloc sim``: render a simulated sequence with ground truth and write it in the TUM RGB-D layout."""

from __future__ import annotations

import click

from sim.cameras import RATE_RANGE_HZ, SIZE_RANGE_PX

SCENES = ("living_room", "office", "apartment", "corridor", "meeting_rooms", "symmetric_room", "random", "building")
CAMERAS = ("oak-d", "kinect", "l515", "wide-tof")
NOISES = ("none", "stereo", "kinect", "tof")


@click.command("sim")
@click.argument("scene", type=click.Choice(SCENES))
@click.option("--trajectory", type=click.Choice(("robot", "handheld", "random")), default="robot", show_default=True,
              help="Robot drive, hand-held walk, or independent random viewpoints (relocalization queries).")
@click.option("--frames", "n_frames", type=click.IntRange(min=1), default=300, show_default=True)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seeds the trajectory and the noise; the scene's world frame does not change with it.")
@click.option("--scene-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Layout seed of the generated scenes (random, building).")
@click.option("--noise", type=click.Choice(NOISES), default="kinect", show_default=True)
@click.option("--camera", type=click.Choice(CAMERAS), default="kinect", show_default=True)
@click.option("--width", type=click.IntRange(*SIZE_RANGE_PX), default=None, help="Resample the camera to this width...")
@click.option("--height", type=click.IntRange(*SIZE_RANGE_PX), default=None, help="...and this height.")
@click.option("--people", type=click.IntRange(min=0), default=0, show_default=True, help="Walking people (clutter).")
@click.option("--rate-hz", type=click.FloatRange(*RATE_RANGE_HZ), default=30.0, show_default=True)
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output directory.")
@click.option("--overwrite", is_flag=True, help="Replace a sequence already in --out.")
def sim(scene, trajectory, n_frames, seed, scene_seed, noise, camera, width, height, people, rate_hz, out_dir,
        overwrite) -> None:
    """Render SCENE along a trajectory and write depth, labels, poses, camera and planes to --out."""
    import time

    from drivers.readers import noise_law_entry
    from reloc._numba import warm_up
    from sim import make_camera
    from sim.writer import write_sequence

    if (width is None) != (height is None):
        raise click.BadParameter("give both --width and --height, or neither", param_hint="--width/--height")
    warm_up(("sim._render_kernels",))
    t0 = time.perf_counter()
    cam = make_camera(scene, trajectory, n_frames, noise, camera, seed, scene_seed=scene_seed, people=people,
                      rate_hz=rate_hz, width=width, height=height)
    t_traj = time.perf_counter() - t0
    meta = {"trajectory": trajectory, "seed": seed, "noise": noise, "noise_model": _noise_dict(cam.noise),
            "camera": camera, "people": people, "rate_hz": rate_hz, "n_frames": len(cam),
            "noise_law": noise_law_entry(cam.noise.extraction_law(cam.intrinsics.fx))}
    s = write_sequence(iter(cam), cam.scene, out_dir, overwrite=overwrite, metadata=meta,
                       progress=len(cam) >= 50, total=len(cam))  # a log gets a line every 10 s
    fps = s.n_frames / max(s.seconds, 1e-9)
    click.echo(f"wrote {s.n_frames} frames of {scene} ({cam.scene.n_planes} planes) to {s.out_dir}")
    click.echo(f"  camera {camera} {s.width}x{s.height}, noise {noise}, trajectory {trajectory}, seed {seed}"
               + (f", {people} people" if people else ""))
    click.echo(f"  valid pixels {100 * s.valid_fraction:.1f}%, labelled {100 * s.labelled_fraction:.1f}%, "
               f"median {s.visible_planes_median:.0f} planes per frame")
    click.echo(f"  {s.seconds:.1f} s ({fps:.0f} frames/s) + {t_traj:.1f} s trajectory; files: depth/ labels/ "
               "depth.txt labels.txt groundtruth.txt gravity.txt camera.yaml planes.json sim.json")
    if s.unrepresentable_pixels:
        click.echo(f"  note: {s.unrepresentable_pixels} pixels lay beyond 65535 / depth_scale = "
                   f"{65535 / s.depth_scale:.1f} m and were written as 0 (no measurement)")


def _noise_dict(model) -> dict:
    from dataclasses import asdict

    return {k: (None if isinstance(v, float) and v == float("inf") else v) for k, v in asdict(model).items()}
