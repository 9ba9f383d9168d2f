"""``resection convert-camera``: rewrite a camera file in another family (argument parsing
only; the formats live in :mod:`resection.io.cameras`)."""

from __future__ import annotations

import os

from resection.errors import InputError


def register(sub) -> None:
    c = sub.add_parser(
        "convert-camera",
        help="rewrite a camera file as native JSON, uPSP JSON or OpenCV YAML/XML",
        description="Read a camera file of any family (recognised by content) and write it "
                    "in the one asked for.",
    )
    c.add_argument("camera", help="input camera file (JSON, uPSP camera-to-tunnel or "
                   "camera-to-model JSON, OpenCV YAML/XML)")
    c.add_argument("--out", required=True, help="output camera file")
    c.add_argument("--format", default="auto",
                   choices=("auto", "json", "upsp", "upsp-model", "opencv-yaml", "opencv-xml"),
                   help="output family (auto: OpenCV for .yml/.yaml/.xml, else JSON; upsp: "
                        "uPSP camera-to-tunnel; upsp-model: uPSP camera-to-model, as "
                        "psp_process reads it)")
    c.add_argument("--image", help="an image of the camera: its size, for a uPSP file that "
                   "gives none (sensor_resolution / imageSize)")
    c.add_argument("--intrinsics-only", action="store_true",
                   help="leave the pose out (an internal calibration file)")
    c.set_defaults(func=_convert)


def _convert(args) -> int:
    from resection.io.cameras import read_camera_file, write_camera

    if os.path.abspath(args.out) == os.path.abspath(args.camera):
        raise InputError(f"{args.out}: the output would overwrite the input camera file")
    size = None
    if args.image:
        from resection.io.images import read_image

        img = read_image(args.image)
        size = (img.shape[1], img.shape[0])
    cf = read_camera_file(args.camera, image_size=size)
    from resection.camera.distortion import lens_problem

    cam = cf.camera
    problem = lens_problem(cam.dist, cam.K, cam.width, cam.height)
    if problem:
        raise InputError(f"{args.camera}: {problem}")
    write_camera(args.out, cf.camera, format=args.format, sensor_size=cf.sensor_size,
                 channels=cf.channels, intrinsics_only=args.intrinsics_only or not cf.has_pose,
                 extra=cf.extra, solved_on=cf.solved_on)
    print(f"{args.camera} ({cf.format}) -> {args.out}")
    return 0
