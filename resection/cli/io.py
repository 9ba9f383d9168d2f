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
    c.add_argument("camera", help="input camera file (JSON, uPSP JSON, OpenCV YAML/XML)")
    c.add_argument("--out", required=True, help="output camera file")
    c.add_argument("--format", default="auto",
                   choices=("auto", "json", "upsp", "opencv-yaml", "opencv-xml"),
                   help="output family (auto: OpenCV for .yml/.yaml/.xml, else JSON)")
    c.add_argument("--intrinsics-only", action="store_true",
                   help="leave the pose out (an internal calibration file)")
    c.set_defaults(func=_convert)


def _convert(args) -> int:
    from resection.io.cameras import read_camera_file, write_camera

    if os.path.abspath(args.out) == os.path.abspath(args.camera):
        raise InputError(f"{args.out}: the output would overwrite the input camera file")
    cf = read_camera_file(args.camera)
    write_camera(args.out, cf.camera, format=args.format, sensor_size=cf.sensor_size,
                 channels=cf.channels, intrinsics_only=args.intrinsics_only or not cf.has_pose)
    print(f"{args.camera} ({cf.format}) -> {args.out}")
    return 0
