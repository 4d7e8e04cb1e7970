"""Write a printable rotating-plate target field, or a standard board (--board BOARD.toml), as a true-scale PDF and
PNG with its target CSV (ids = the board's corner indices) and layout."""
from __future__ import annotations

import argparse
import dgcal.arg_types as arg_types  # not `from dgcal import`: dgcal.__getattr__ would load the API

NAME = "field"
HELP = "write a printable ChArUco target plate or a standard board (PDF, PNG) and its field CSV"
OUTPUTS = {"field": "field.csv", "pdf": "field.pdf", "png": "field.png", "tiles": "field_tiles_{page}.pdf",
           "board": "board.toml"}
# (the layout field.json is written beside field.csv)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output directory (field.csv, field.json, field.pdf, field.png)")
    p.add_argument("--board", metavar="BOARD.toml",
                   help="a standard board (charuco, chessboard, aruco-grid) instead of the rotating plate: writes its "
                        "field.csv (ids = corner indices), board.toml and a printable sheet")
    p.add_argument("--diameter", type=arg_types.positive, default=2.4, help="plate diameter (m, default 2.4)")
    p.add_argument("--square", type=arg_types.positive, default=0.08, help="chessboard square (m, default 0.08)")
    p.add_argument("--marker", type=arg_types.positive, default=0.06, help="ArUco marker side (m, default 0.06)")
    p.add_argument("--dictionary", default="DICT_5X5_1000", help="OpenCV ArUco dictionary (default DICT_5X5_1000)")
    p.add_argument("--nonplanar", action="store_true", help="add four raised blocks (0.10 m and 0.20 m high)")
    p.add_argument("--sigma-xy", type=arg_types.positive, default=0.0002, help="target sigma in the plate plane (m)")
    p.add_argument("--sigma-z", type=arg_types.positive, default=0.0005, help="target sigma across the plate (m)")
    p.add_argument("--dpi", type=arg_types.positive, default=None,
                   help="PNG resolution (dots per inch, default 100; 300 for a "
                   "board)")
    p.add_argument("--no-png", action="store_true", help="skip the PNG raster")
    p.add_argument("--tiles", choices=("A4", "A3", "A2", "A1", "A0"),
                   help="also write field_tiles_<page>.pdf: the plate on landscape sheets, 10 mm overlap")


def run(args: argparse.Namespace) -> int:
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.fields.targets.plate import FieldOptions, make_target_field
    from dgcal.fields.targets.printing import write_field_files

    if args.board:
        return _run_board(args)
    args.dpi = 100.0 if args.dpi is None else args.dpi

    tf = make_target_field(FieldOptions(diameter_m=args.diameter, square_m=args.square, marker_m=args.marker,
                                        dictionary=args.dictionary, nonplanar=args.nonplanar,
                                        sigma_xy_m=args.sigma_xy, sigma_z_m=args.sigma_z))
    with staged_dir(args.out) as tmp:
        paths = write_field_files(tmp, tf, OUTPUTS, png_dpi=None if args.no_png else args.dpi, tiles=args.tiles)
    if args.tiles:
        print(f"{paths['tiles'].name}: {paths['tile_pages']} pages")
    print(f"{len(tf.points().ids)} targets, {tf.n_printed_markers()} markers on a {tf.diameter_m:g} m plate: "
          f"wrote field.csv, field.json, field.pdf{'' if args.no_png else ', field.png'} to {args.out}")
    return 0


def _run_board(args: argparse.Namespace) -> int:
    """`dgcal field --board`: the board's field CSV, board.toml and printable sheet."""
    from dgcal.fields.io.csv_tables import staged_dir
    from dgcal.fields.targets.boards import read_board
    from dgcal.fields.targets.printing import write_board_files

    board = read_board(args.board)
    with staged_dir(args.out) as tmp:
        write_board_files(tmp, board, OUTPUTS, png_dpi=None if args.no_png else (args.dpi or 300.0))
    print(f"{board.describe()}: {board.n_corners} corners; wrote field.csv, field.json, board.toml, field.pdf"
          f"{'' if args.no_png else ', field.png'} to {args.out}")
    return 0
