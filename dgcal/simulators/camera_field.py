"""Rendered photos of the rotating coded-target plate, or of a standard board (--board), with known fraser7 truth
(dgcal.sim.camera_field)."""
from __future__ import annotations

import argparse

from dgcal.calib.camera.files import load_camera
from dgcal.fields.targets.boards import read_board
from dgcal.fields.targets.plate import FieldOptions, make_target_field
from dgcal.sim import camera_field
from dgcal.sim.camera_field import simulate_board_views, simulate_camera_field
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "camera-field"
HELP = "rendered photos of the rotating coded-target plate (or of a standard board) with known fraser7 truth"
DESCRIPTION = camera_field.__doc__  # --help shows the simulator's own documentation


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-images", type=int, default=None, help="images (default 48; 30 with --board)")
    p.add_argument("--image-size", type=int, nargs=2, default=None, metavar=("W", "H"),
                   help="image size in pixels (default 3000 2000, 1200 800 with --board; 5472 3648 for a 20 MP camera)")
    p.add_argument("--camera", help="truth camera.json (default: a built-in fraser7 lens for the image size)")
    p.add_argument("--nonplanar", action="store_true", help="plate with four raised blocks (0.1 m, 0.2 m)")
    p.add_argument("--diameter", type=arg_types.positive, default=2.4, help="plate diameter (m)")
    p.add_argument("--square", type=arg_types.positive, default=0.08, help="chessboard square (m)")
    p.add_argument("--marker", type=arg_types.positive, default=0.06, help="ArUco marker side (m)")
    p.add_argument("--dictionary", default="DICT_5X5_1000")
    p.add_argument("--blur", type=arg_types.finite, default=0.8, help="Gaussian optical blur sigma (px)")
    p.add_argument("--noise", type=arg_types.finite, default=2.0, help="Gaussian noise sigma (8-bit DN)")
    p.add_argument("--jpeg-quality", type=int, default=95)
    p.add_argument("--board", metavar="BOARD.toml",
                   help="render hand-held views of this standard board (charuco, chessboard, aruco-grid) instead of "
                        "the plate (PNG images; default 30 images of 1200 x 800 unless given)")
    p.add_argument("--mirrored", action="store_true", help="with --board: every view flipped (the back face)")


def run(args: argparse.Namespace) -> int:
    if args.board:
        n = 30 if args.n_images is None else args.n_images
        size = (1200, 800) if args.image_size is None else tuple(args.image_size)
        simulate_board_views(args.out, read_board(args.board), args.seed, n, size,
                             load_camera(args.camera) if args.camera else None, blur_px=args.blur, noise_dn=args.noise,
                             mirrored=args.mirrored)
        print(f"wrote {n} images, board.toml, field.csv, truth.json and truth_measurements.csv to {args.out}")
        return 0
    tf = make_target_field(FieldOptions(diameter_m=args.diameter, square_m=args.square, marker_m=args.marker,
                                        dictionary=args.dictionary, nonplanar=args.nonplanar))
    args.n_images = 48 if args.n_images is None else args.n_images
    simulate_camera_field(args.out, args.seed, args.n_images, (3000, 2000) if args.image_size is None
                          else tuple(args.image_size),
                          load_camera(args.camera) if args.camera else None, tf,
                          blur_px=args.blur, noise_dn=args.noise, jpeg_quality=args.jpeg_quality)
    print(f"wrote {args.n_images} images, field.csv, truth.json and truth_measurements.csv to {args.out}")
    return 0
