"""Real-camera commands: `ovis intrinsics` (lens from board photos) and `ovis locate`
(the floor position of pixels)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import JsonOpt

__all__ = ["BoardOriginOpt", "BoardRowEndOpt", "register"]

BoardOpt = Annotated[
    str | None,
    typer.Option(
        help="The board: chessboard:COLSxROWS (inner corners, e.g. chessboard:9x6) or "
        "charuco:COLSxROWS:DICT (squares, e.g. charuco:7x5:DICT_5X5_100)."
    ),
]
SquareOpt = Annotated[
    float, typer.Option("--square-cm", help="Side of one board square (cm).", min=1e-6)
]
MarkerOpt = Annotated[
    float | None,
    typer.Option("--marker-cm", help="ChArUco only: side of a marker (cm).", min=1e-6),
]

BoardOriginOpt = Annotated[
    str | None,
    typer.Option(
        "--board-origin",
        help="With --board: X,Y (cm), where the board's origin corner (its first inner "
        "corner: the top-left one seen from above with its rows of COLS corners left to "
        "right and a black corner square at its top left) lies on the arena floor. With "
        "--board-row-end the calibration is in the arena's frame, not the board's.",
    ),
]
BoardRowEndOpt = Annotated[
    str | None,
    typer.Option(
        "--board-row-end",
        help="With --board-origin: X,Y (cm), where the last inner corner of the board's "
        "first row lies on the arena floor (its distance from the origin corner must be "
        "the board's, within 2 % or 0.5 cm).",
    ),
]


def _floor_xy(text: str, option: str) -> tuple[float, float]:
    """'X,Y' as two finite floats (cm), or a one-line error naming ``option``."""
    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise UserError(f"{option} must be X,Y in cm, got {text!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise UserError(f"{option} must be finite, got {text!r}")
    return x, y


def _board_placement(board: str | None, origin: str | None, row_end: str | None):
    """The board's placement in the arena from --board-origin and --board-row-end (both or
    neither, only with --board), or None."""
    from ovis.common.calibration.floor import BoardPlacement

    if origin is None and row_end is None:
        return None
    if board is None:
        raise UserError("--board-origin and --board-row-end place a --board: give --board too")
    if origin is None or row_end is None:
        raise UserError(
            "give both --board-origin X,Y and --board-row-end X,Y (the board's origin corner "
            "and the last inner corner of its first row, measured on the arena floor in cm)"
        )
    return BoardPlacement(
        origin_cm=_floor_xy(origin, "--board-origin"),
        row_end_cm=_floor_xy(row_end, "--board-row-end"),
    )


def board_spec(board: str | None, square_cm: float, marker_cm: float | None):
    """The parsed --board, or a one-line error saying the expected form."""
    from ovis.common.vision.boards import BoardError, parse_board

    if board is None:
        raise UserError("give --board chessboard:COLSxROWS or charuco:COLSxROWS:DICT")
    try:
        return parse_board(board, square_cm, marker_cm)
    except BoardError as exc:
        raise UserError(str(exc)) from None


def _image_files(paths: list[Path]) -> list[Path]:
    """The image files named, a folder standing for the images in it (name order)."""
    from ovis.common.capture.sources import IMAGE_SUFFIXES

    files: list[Path] = []
    for p in paths:
        if p.is_dir():
            inside = sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
            if not inside:
                raise UserError(f"folder {p} holds no images ({', '.join(IMAGE_SUFFIXES)})")
            files += inside
        else:
            files.append(p)
    return files


def _stream_views(source: str, spec, max_views: int, max_frames: int, min_shift_px: float, con):
    """Frames of a capture source, keeping up to ``max_views`` distinct views of the board."""
    from ovis.common.capture.sources import SourceError, open_source
    from ovis.common.config import load_config
    from ovis.common.vision.boards import find_board
    from ovis.common.vision.frames import as_gray

    cfg = load_config()
    try:
        src = open_source(source, cfg, loop=False)
    except SourceError as exc:
        raise UserError(str(exc)) from None
    kept, found, rejected = [], [], []
    size = None
    from ovis.common.calibration.intrinsics import FoundView, RejectedView, distinct_view

    try:
        for i in range(max_frames):
            try:
                image, _ = src.read()
            except SourceError:
                break
            gray = as_gray(image)
            size = size or (gray.shape[1], gray.shape[0])
            name = f"{source}#{i}"
            view = find_board(gray, spec)
            if view is None:
                rejected.append(RejectedView(view=name, reason=f"{spec.describe()} not found"))
            elif distinct_view(view, kept, min_shift_px):
                kept.append(view)
                found.append(FoundView(name, view))
                con.print(f"  kept view {len(found)}/{max_views} ({name})")
                if len(found) >= max_views:
                    break
    finally:
        src.close()
    if size is None:
        raise UserError(f"{source} delivered no frame")
    return found, rejected, size


def intrinsics(
    images: Annotated[
        list[Path] | None,
        typer.Argument(help="Photos of the board (files or folders), one camera, one size."),
    ] = None,
    board: BoardOpt = None,
    square_cm: SquareOpt = 1.0,
    marker_cm: MarkerOpt = None,
    out: Annotated[
        Path | None, typer.Option(help="Where to write CAM.yaml (OpenCV calibration format).")
    ] = None,
    plot: Annotated[
        Path | None, typer.Option(help="Write the corner coverage of the image (PNG).")
    ] = None,
    source: Annotated[
        str | None,
        typer.Option(
            help="Take the views from a capture source instead: camera:N, a video, a "
            "stream URL or a folder; distinct views of the board are kept."
        ),
    ] = None,
    max_views: Annotated[int, typer.Option(min=3, help="--source: views to keep.")] = 20,
    max_frames: Annotated[int, typer.Option(min=1, help="--source: frames to look at.")] = 600,
    min_shift_px: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="--source: a view is kept when its corners moved this "
            "far on average from every kept view.",
        ),
    ] = 40.0,
    drop_outliers: Annotated[
        bool, typer.Option(help="Calibrate again without the views flagged as outliers.")
    ] = False,
    json: JsonOpt = False,
) -> None:
    """Calibrate a lens (K and distortion) from photos of a printed board.

    Uses OpenCV's detectors (findChessboardCorners + cornerSubPix in a window reaching
    half the view's smallest square around each corner, or CharucoDetector) and
    calibrateCamera (five distortion coefficients). Reports the overall and per-view RMS
    reprojection error (px), names the views where the board was not found, flags outlier
    views (RMS above 3x the median view's) and shows how much of the image the corners
    covered: uncovered image corners mean the distortion there is a guess. Writes CAM.yaml
    in OpenCV's calibration format (cv2.FileStorage reads it; so do `ovis calibrate
    --intrinsics` and `ovis export`).
    """
    from rich.console import Console

    from ovis.common.calibration.intrinsics import (
        IntrinsicsError,
        calibrate_intrinsics,
        detect_views,
    )
    from ovis.common.vision.imageio import read_image
    from ovis.services.cli.ui import emit_json

    spec = board_spec(board, square_cm, marker_cm)
    if out is None and not json:
        raise UserError("give --out CAM.yaml (and/or --json)")
    for target in (out, plot):
        if target is not None and target.is_dir():
            raise UserError(f"{target} is a folder; give a file name")
    if bool(images) == bool(source):
        raise UserError("give the board photos (IMAGE...) or --source, not both or neither")
    con = Console(highlight=False, quiet=json)  # progress on stdout: errors alone on stderr
    if source is not None:
        views = _stream_views(source, spec, max_views, max_frames, min_shift_px, con)
        backdrop = None
    else:
        files = _image_files(images or [])
        frames = [(p.name, read_image(p)) for p in files]

        def on_view(name: str, ok: bool) -> None:
            con.print(f"  {name}: {'board found' if ok else 'no board'}")

        def on_skipped(odd: list[tuple[str, tuple[int, int]]], size: tuple[int, int]) -> None:
            names = ", ".join(f"{name} ({w}x{h})" for name, (w, h) in odd)
            print(
                f"warning: skipped {len(odd)} image(s) of another size than the "
                f"{size[0]}x{size[1]} most of them share: {names}",
                file=sys.stderr,
            )

        views = detect_views(frames, spec, on_view=on_view, on_skipped=on_skipped)
        backdrop = next(img for _, img in frames if (img.shape[1], img.shape[0]) == views[2])
    try:
        report = calibrate_intrinsics(None, spec, views=views, drop_outliers=drop_outliers)
    except IntrinsicsError as exc:
        raise UserError(str(exc)) from None
    if out is not None:
        from ovis.common.camera.intrinsics import write_intrinsics

        note = f"ovis intrinsics: {report.board}, {len(report.views_used)} views"
        write_intrinsics(out, report.intrinsics(), note=note)
    if plot is not None:
        from ovis.common.analysis.coverage import plot_coverage
        from ovis.common.vision.frames import as_gray

        used = set(report.views_used)
        corners = [f.view.image_xy for f in views[0] if f.name in used]
        plot_coverage(plot, report, corners, None if backdrop is None else as_gray(backdrop))
    for text in report.warnings:
        print(f"warning: {text}", file=sys.stderr)
    if json:
        emit_json(report)
        return
    _print_intrinsics(report, out, plot)


def _print_intrinsics(report, out: Path | None, plot: Path | None) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(highlight=False)
    (fx, _, cx), (_, fy, cy), _ = report.camera_matrix
    t = Table(title=f"views ({report.board})", title_justify="left")
    for col in ("view", "corners", "window px", "RMS px", "flag"):
        t.add_column(col, justify="right")
    for v in report.per_view:
        window = "-" if v.window_px is None else str(v.window_px)
        flag = "OUTLIER" if v.outlier else ""
        t.add_row(v.view, str(v.corners), window, f"{v.rms_px:.3f}", flag)
    con.print(t)
    for r in report.views_rejected:
        con.print(f"rejected {r.view}: {r.reason}")
    con.print(
        f"RMS {report.rms_px:.4f} px over {len(report.views_used)} views; fx {fx:.2f} fy "
        f"{fy:.2f} cx {cx:.2f} cy {cy:.2f} px; k1, k2, p1, p2, k3 = "
        + ", ".join(f"{v:.4g}" for v in report.dist)
    )
    cov = report.coverage
    con.print(
        f"coverage: {cov.fraction:.0%} of a {cov.grid_cols}x{cov.grid_rows} grid, "
        f"{cov.image_corners_covered}/4 image corners"
        + (
            ""
            if cov.image_corners_covered == 4
            else " - take photos with the board in the corners of the image"
        )
    )
    if report.outliers:
        what = "dropped" if report.outliers_dropped else "kept (use --drop-outliers to drop)"
        con.print(f"outlier views {', '.join(report.outliers)}: {what}")
    wrote = [str(p) for p in (out, plot) if p is not None]
    if wrote:
        con.print("wrote " + " and ".join(wrote))


def register(app: typer.Typer) -> None:
    """Add the real-camera commands to the `ovis` app."""
    app.command()(intrinsics)
    app.command()(locate)


def refuse_implausible(calib, force: bool, extra: list[str] | None = None) -> list[str]:
    """Stop (exit 3, nothing written) on an implausible calibration (or for ``extra``
    reasons) unless ``force``; with ``force``, return the reasons to print as a warning."""
    from ovis.common.calibration.plausibility import plausibility

    reasons, suspicious = plausibility(calib)
    reasons = reasons + (extra or [])
    if reasons and not force:
        raise UserError(
            "implausible calibration, not saved: " + "; ".join(reasons) + " (check the "
            "control points and ranges; --force saves it anyway)",
            3,
        )
    for text in suspicious:
        print(f"warning: {text}", file=sys.stderr)
    return reasons


def _known_lens_points(gray, intr, points, board, square_cm, marker_cm, markers, placed):
    """Pixel-known control points from --points, --board (in the arena's frame where it
    is ``placed``) or --markers."""
    from ovis.common.calibration.floor import board_points, load_markers, marker_points
    from ovis.common.config import load_points
    from ovis.common.vision.boards import find_markers

    given = [x is not None for x in (points, board, markers)]
    if sum(given) != 1:
        raise UserError("give one of --points, --board or --markers")
    if board is not None:
        return board_points(gray, board_spec(board, square_cm, marker_cm), placed), None
    if markers is not None:
        survey = load_markers(markers)
        try:
            found = find_markers(gray, survey.dictionary)
        except ValueError as exc:
            raise UserError(f"markers file {markers}: {exc}") from None
        return marker_points(found, survey), None
    pts = load_points(points)
    return pts.points, pts


def calibrate_known_lens(
    image: Path,
    *,
    intrinsics: Path | None,
    points: Path | None,
    board: str | None,
    square_cm: float | None,
    marker_cm: float | None,
    markers: Path | None,
    point_px: float | None,
    config: Path | None,
    preset: str | None,
    out: Path,
    json: bool,
    force: bool,
    quiet: bool,
    board_origin: str | None = None,
    board_row_end: str | None = None,
) -> None:
    """`ovis calibrate --intrinsics`: the floor pose with the lens fixed (see
    :mod:`ovis.common.calibration.floor`), judged against what the lens and the points'
    precision explain (:mod:`ovis.common.calibration.lens_check`; printed even when
    refused); blob points go to the GA with the lens fixed. A board placed with
    ``board_origin`` and ``board_row_end`` (X,Y cm) gives a calibration in the arena's
    frame."""
    import msgspec

    from ovis.common.calibration.file import save_calibration
    from ovis.common.calibration.floor import (
        FloorPoseError,
        check_image_size,
        known_lens_config,
        place_board,
        solve_floor_pose,
    )
    from ovis.common.calibration.lens_check import BOARD_PX, CLICK_PX, distortion_problems
    from ovis.common.camera.intrinsics import IntrinsicsFileError, read_intrinsics
    from ovis.common.config import resolve_config
    from ovis.common.vision.frames import as_gray
    from ovis.common.vision.imageio import read_image
    from ovis.services.cli.ui import emit_json

    placement = _board_placement(board, board_origin, board_row_end)
    if intrinsics is None:
        raise UserError("--board and --markers need --intrinsics CAM.yaml (from `ovis intrinsics`)")
    if board is not None and square_cm is None:
        raise UserError(
            "--board needs --square-cm: the side of one printed square in cm (measure it); "
            "the camera's position comes out in those units"
        )
    if out.is_dir():
        raise UserError(f"{out} is a folder; give a file name")
    try:
        intr = read_intrinsics(intrinsics)
    except IntrinsicsFileError as exc:
        raise UserError(str(exc)) from None
    gray = as_gray(read_image(image))
    extra: list[str] = []
    try:
        check_image_size(intr, gray.shape[1], gray.shape[0], f"image {image}")
        placed = None
        if placement is not None:
            placed = place_board(board_spec(board, square_cm or 1.0, marker_cm), placement)
        pts, pts_file = _known_lens_points(
            gray, intr, points, board, square_cm or 1.0, marker_cm, markers, placed
        )
        cfg = resolve_config(config, preset, pts_file.config if pts_file else None)
        pitch = (
            getattr(cfg.camera, "pixel_pitch_mm", None) if cfg.camera.model == "pinhole" else None
        )
        if all(p.pixel_known for p in pts):
            default_px = BOARD_PX if board is not None else CLICK_PX
            calib = solve_floor_pose(
                intr,
                pts,
                image_size=(gray.shape[1], gray.shape[0]),
                image=cfg.image,
                pose=cfg.pose,
                pixel_pitch_mm=pitch,
                source=str(image),
                point_px=default_px if point_px is None else point_px,
                lens_name=str(intrinsics),
                frame=None if placed is None else placed.note,
            )
        else:
            from ovis.services.cli.ui import calibrate_with_progress

            extra = distortion_problems(intr, str(intrinsics))
            cfg = known_lens_config(cfg, intr)
            calib = calibrate_with_progress(
                gray, pts, cfg, source=str(image), show=not quiet and not json
            )
    except FloorPoseError as exc:
        raise UserError(str(exc)) from None
    calib = msgspec.structs.replace(calib, source_image=str(image))
    if json:
        emit_json(calib)
    else:
        _print_floor_pose(calib, intr)
    warnings = refuse_implausible(calib, force, extra)
    save_calibration(out, calib)
    if not json:
        from ovis.services.cli.ui import console

        for w in warnings:
            console().print(f"WARNING (forced): {w}")
        console().print(f"wrote {out}")


def _print_floor_pose(calib, intr) -> None:
    """Where the camera is, each control point's residual and how the residuals compare
    with what the lens explains (also for a pose about to be refused)."""
    from ovis.common.calibration.file import dipe_text
    from ovis.common.calibration.lens_check import viewing
    from ovis.services.cli.reports import print_accuracy
    from ovis.services.cli.ui import console, table

    con = console()
    cam = calib.camera
    height, tilt = viewing(cam)
    con.print(
        f"camera {height:.2f} cm above the floor (z = 0), its axis {tilt:.1f}° from straight "
        f"down; lens fx {cam.fx:.2f} fy {cam.fy:.2f} cx {cam.cx:.2f} cy {cam.cy:.2f} px "
        "(fixed)"
    )
    rep = calib.accuracy
    check = rep.lens if rep is not None else None
    loo = {p.name: p for p in rep.leave_one_out.points} if rep and rep.leave_one_out else {}
    columns = ["point", "X,Y,Z cm", "row,col", "px", "cm"]
    columns += ["LOO px", "LOO cm"] if loo else []
    title = "control points: pixel, residual (px; cm on the floor)"
    t = table(title + (", held out (leave-one-out)" if loo else ""), columns)
    cms = check.residual_cm if check is not None else [None] * len(calib.points)
    for r, cm in zip(calib.points, cms, strict=True):
        row = [
            r.name,
            f"{r.x_cm:g},{r.y_cm:g},{r.z_cm:g}",
            f"{r.detected_row:.2f},{r.detected_col:.2f}",
            f"{r.dipe_px:.3f}",
            "-" if cm is None else f"{cm:.3f}",
        ]
        if loo:
            h = loo[r.name]
            row += [f"{h.error_px:.3f}", "-" if h.error_cm is None else f"{h.error_cm:.3f}"]
        t.add_row(*row)
    con.print(t)
    lens_rms = "not stated" if intr.rms_px is None else f"{intr.rms_px:.3f} px"
    line = (
        f"{len(calib.points)} control points: DIPE mean "
        f"{dipe_text(calib.dipe_px, calib.dipe_mm)}, max "
        f"{dipe_text(calib.dipe_max_px, calib.dipe_max_mm)}; lens RMS {lens_rms}"
    )
    if check is not None:
        line += f"; residual RMS {check.rms_px:.3f} px"
        if check.allowed_rms_px is not None:
            verdict = "explained" if check.explained else "NOT explained"
            line += (
                f", {verdict} (at most {check.allowed_rms_px:.3f} px for the lens and the "
                f"points' precision {check.point_px:g} px)"
            )
    con.print(line)
    if loo:
        held = rep.leave_one_out
        cm = "" if held.mean_cm is None else f" = {held.mean_cm:.3f} cm"
        con.print(
            f"held out (leave-one-out): mean {held.mean_px:.3f} px{cm}, max {held.max_px:.3f} px"
        )
    if rep is not None:  # its notes (the held-out errors are in the table above)
        import msgspec

        shown = msgspec.structs.replace(rep, leave_one_out=None)
        print_accuracy(msgspec.structs.replace(calib, accuracy=shown), con)


def _pixel(text: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        row, col = (float(p) for p in parts)
    except ValueError:
        raise UserError(f"--pixel must be ROW,COL in pixels, got {text!r}") from None
    if not all(map(math.isfinite, (row, col))):
        raise UserError(f"--pixel must be finite, got {text!r}")
    return row, col


def locate(
    calibration: Annotated[Path, typer.Argument(help="Calibration JSON (`ovis calibrate`).")],
    pixel: Annotated[list[str], typer.Option(help="A pixel ROW,COL (px); repeat for several.")],
    z_cm: Annotated[
        float, typer.Option("--z-cm", help="Height of the plane the pixels lie on (cm).")
    ] = 0.0,
    json: JsonOpt = False,
) -> None:
    """The floor position (cm) of pixels: the back-projection the pose stage uses.

    Works for any calibration (the paper's model or a pinhole). A pixel outside the
    image, or one whose ray does not meet the plane, is an error.
    """
    from ovis.common.calibration.file import load_calibration
    from ovis.common.camera.projection import back_project
    from ovis.services.cli.ui import emit_json

    if not math.isfinite(z_cm):
        raise UserError("--z-cm must be a finite height in cm")
    calib = load_calibration(calibration)
    cam = calib.camera
    pixels = [_pixel(p) for p in pixel]
    for row, col in pixels:
        if not (0 <= row <= cam.rows - 1 and 0 <= col <= cam.cols - 1):
            raise UserError(
                f"pixel ({row:g}, {col:g}) is outside the {cam.cols}x{cam.rows} image of "
                f"{calibration} (row 0..{cam.rows - 1}, col 0..{cam.cols - 1})"
            )
    rows, cols = (np.array(v, dtype=np.float64) for v in zip(*pixels, strict=True))
    b = back_project(rows, cols, cam, z_cm)
    if not b.valid.all():
        bad = [f"({r:g}, {c:g})" for (r, c), ok in zip(pixels, b.valid, strict=True) if not ok]
        raise UserError(f"pixel(s) {', '.join(bad)} do not see the plane z = {z_cm:g} cm")
    found = [
        {"row": r, "col": c, "x_cm": float(x), "y_cm": float(y)}
        for (r, c), x, y in zip(pixels, b.x_cm, b.y_cm, strict=True)
    ]
    if json:
        emit_json(found)
        return
    for f in found:
        print(f"row {f['row']:g}, col {f['col']:g} -> x {f['x_cm']:.3f} cm, y {f['y_cm']:.3f} cm")


def with_image_flags(
    params,
    *,
    threshold: str | None = None,
    size_filter: float | None = None,
    max_size: float | None = None,
    block_px: int | None = None,
    polarity: str | None = None,
    background: Path | None = None,
    roi: Path | None = None,
):
    """ImageParams with `ovis detect`'s flags applied (sizes in cm²: with a calibration)."""
    import msgspec

    from ovis.common.vision.threshold import parse_threshold

    fields: dict = {}
    if threshold is not None:
        try:
            fields |= parse_threshold(threshold)
        except ValueError as exc:
            raise UserError(str(exc)) from None
    if polarity is not None:
        if polarity not in ("bright", "dark"):
            raise UserError(f"--polarity must be 'bright' or 'dark', got {polarity!r}")
        fields["polarity"] = polarity
    for name, path in (("background", background), ("roi", roi)):
        if path is not None:
            if not path.is_file():
                raise UserError(f"--{name} {path} does not exist")
            fields[name] = str(path)
    if block_px is not None:
        fields["block_px"] = block_px | 1
    if size_filter is not None:
        fields["size_filter_cm2"] = size_filter
    if max_size is not None:
        fields["max_size_cm2"] = max_size
    return msgspec.structs.replace(params, **fields)


def detect_without_calibration(images: list[Path], flags: dict, *, json: bool, overlay) -> None:
    """`ovis detect` with no calibration: blobs in pixels (sizes in px), automatic
    threshold unless --threshold."""
    from rich.console import Console
    from rich.table import Table

    from ovis.common.config import ImageParams
    from ovis.common.vision.imageio import read_image
    from ovis.common.world.pixels import detect_pixels
    from ovis.services.cli.ui import emit_json

    size_filter, max_size = flags.pop("size_filter"), flags.pop("max_size")
    params = with_image_flags(ImageParams(median="ordinary", threshold_mode="auto"), **flags)
    results = []
    for i, path in enumerate(images):
        frame = read_image(path)
        found = detect_pixels(frame, params, min_area_px=size_filter, max_area_px=max_size)
        results.append(
            {
                "image": str(path),
                "objects": found.objects,
                "min_area_px": found.min_area_px,
                "background_blobs": found.background,
                "window_px": found.window_px,
                "level": found.level,
            }
        )
        if overlay is not None:
            _draw_pixel_objects(frame, found.objects, overlay, i, len(images))
    if json:
        emit_json(results[0] if len(results) == 1 else results)
        return
    con = Console(highlight=False)
    for r, path in zip(results, images, strict=True):
        behind = r["background_blobs"]
        t = Table(
            title=f"{path}: {len(r['objects'])} object(s), pixels only (no calibration; "
            f"threshold {params.threshold_mode}: {_threshold_said(r)}, smallest "
            f"{r['min_area_px']:.0f} px"
            + (f"; {behind} background blob left out" if behind else "")
            + ")",
            title_justify="left",
        )
        for col in ("id", "row", "col", "area px", "perim px", "compact."):
            t.add_column(col, justify="right")
        for o in r["objects"]:
            t.add_row(
                str(o.id),
                f"{o.row:.2f}",
                f"{o.col:.2f}",
                f"{o.area_px:.0f}",
                f"{o.perimeter_px:.1f}",
                f"{o.compactness:.3f}",
            )
        con.print(t)


def _threshold_said(r: dict) -> str:
    """The level, and the local-contrast window when there is one."""
    if r["window_px"]:
        return f"level {r['level']}, local window {r['window_px']} px"
    return f"level {r['level']}"


def _draw_pixel_objects(frame, found, overlay: Path, index: int, count: int) -> None:
    import cv2

    from ovis.common.analysis.plots import save_png

    canvas = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame.copy()
    for o in found:
        centre = (round(o.col), round(o.row))
        cv2.drawMarker(canvas, centre, (40, 140, 255), cv2.MARKER_CROSS, 12, 2)
        cv2.putText(
            canvas,
            str(o.id),
            (centre[0] + 6, centre[1] - 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (40, 140, 255),
            1,
        )
    target = overlay
    if count > 1:
        target = overlay.with_name(f"{overlay.stem}_{index:04d}{overlay.suffix or '.png'}")
    save_png(target, canvas)
