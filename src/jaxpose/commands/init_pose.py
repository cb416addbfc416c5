"""``jaxpose init IMAGE --camera CAMERA.json [--model tango|FILE] [--overlay OUT.png] [--roi U0 V0
U1 V1] [--option NAME=VALUE ...]``: the pose of the target in one image with no prior (Sharma et
al. 2018), printed as one JSON object."""

from __future__ import annotations

import json

from jaxpose.commands._common import add_option_argument, add_progress_argument, with_options


def add_arguments(parser) -> None:
    parser.add_argument("image", help="image file (any format OpenCV reads)")
    parser.add_argument(
        "--camera", required=True, help="camera.json (SPEED layout: cameraMatrix, distCoeffs)"
    )
    parser.add_argument(
        "--model", default="tango", help="'tango' (built in), a model .json, or a mesh (STL/OBJ)"
    )
    parser.add_argument(
        "--overlay", help="write an overlay PNG: segments, groups used, projected model"
    )
    parser.add_argument(
        "--method",
        choices=("svd", "ransac"),
        default="svd",
        help="svd (default) or the RANSAC baseline",
    )
    parser.add_argument(
        "--detector", choices=("hough", "lsd"), default="hough", help="line detector"
    )
    parser.add_argument(
        "--roi",
        nargs=4,
        type=float,
        metavar=("U0", "V0", "U1", "V1"),
        help="the target's box in pixels of IMAGE (from a detector): replaces the ROI search "
        "(no silhouette terms then)",
    )
    add_option_argument(
        parser, "InitOptions (jaxpose.pipelines.monocular)", "detection.detector=lsd"
    )
    add_progress_argument(parser)


def run(args) -> int:
    import cv2

    from jaxpose.commands import enable_compilation_cache
    from jaxpose.commands._common import stage
    from jaxpose.io import load_camera
    from jaxpose.pipelines.monocular import InitOptions, draw_overlay, initialise_pose, load_image
    from jaxpose.vision.features import DetectionOptions
    from jaxpose.vision.models import load_model

    enable_compilation_cache()
    camera = load_camera(args.camera)
    model = load_model(args.model)
    image = load_image(args.image)
    opts = InitOptions(method=args.method, detection=DetectionOptions(detector=args.detector))
    opts = with_options(opts, args.option)
    # the first run compiles for about a minute: a ticker on stderr shows it is alive
    with stage("jaxpose init: pose search", enabled=not args.no_progress):
        result = initialise_pose(image, camera, model, opts, roi=args.roi)
    if args.overlay:
        if not cv2.imwrite(args.overlay, draw_overlay(image, result, model)):
            raise ValueError(f"cannot write overlay {args.overlay}")
    print(json.dumps(result.to_json()))
    return 0
