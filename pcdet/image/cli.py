"""`pcdet image ...`: the 2D recognition tools from the command line."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from ..console import guard
from ..errors import InputError
from ..io.jsonfile import read_json
from ..io.outputs import check_file


def _need(doc: dict, keys: tuple[str, ...], path, what: str) -> None:
    """``InputError`` naming the file and the missing fields unless ``doc`` has every key."""
    missing = [k for k in keys if k not in doc]
    if missing:
        raise InputError(f"{what} needs {', '.join(repr(k) for k in keys)}; missing {', '.join(map(repr, missing))}",
                         path)


image_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                        help="Recognition from 2D views: LCM, Hough, homographies.")


def _lcm_part(name: str, spec: dict, thresholds: list[float], table) -> dict[float, bool]:
    from .lcm import LinearCombination

    lc = LinearCombination().fit(spec["views"], spec["points"], allow_degenerate=spec.get("allow_degenerate",
                                                                                          False))
    table(f"{name}: alpha beta gamma delta")
    table(f"  x: {' '.join(f'{v:8.3f}' for v in lc.coef_x)}" + ("" if lc.rank_x == 4 else f"  (rank {lc.rank_x})"))
    table(f"  y: {' '.join(f'{v:8.3f}' for v in lc.coef_y)}" + ("" if lc.rank_y == 4 else f"  (rank {lc.rank_y})"))
    check = spec.get("check")
    if not check:
        table("  no 'check' points: nothing to predict, no match decision")
        return {}
    pred = lc.predict(check["views"])
    res = lc.residuals(check["views"], check["points"])
    for p, o, r in zip(pred, np.asarray(check["points"], float), res):
        table(f"  predicted ({p[0]:.3f}, {p[1]:.3f})  observed ({o[0]:.3f}, {o[1]:.3f})  |difference| "
              f"({r[0]:.3f}, {r[1]:.3f})")
    return {t: bool(np.all(res < t)) for t in thresholds}


@image_app.command("lcm")
def lcm(views_json: Path = typer.Argument(..., help="JSON: views, points, check, thresholds (see --help)."),
        ):
    """Linear Combination Method: fit the coefficients, predict the check points, decide per threshold.

    JSON: {"views": [[[x, y], ...] x >= 3], "points": [[x, y], ...], "check": {"views": [...], "points": [...]},
    "thresholds": [0.2, 0.6]}; an articulated object: {"parts": {"main": {...}, "door": {...}}, "thresholds":
    [...]}, matching only if every part matches.
    """
    @guard
    def go():
        doc = read_json(views_json)
        parts = doc["parts"] if isinstance(doc.get("parts"), dict) else {"object": doc}
        for name, spec in parts.items():
            if not isinstance(spec, dict):
                raise InputError(f"part {name!r} must be an object with 'views' and 'points'", views_json)
            _need(spec, ("views", "points"), views_json, f"part {name!r}" if "parts" in doc else "an LCM file")
        thresholds = [float(t) for t in doc.get("thresholds", [0.2])]
        try:
            decisions = {name: _lcm_part(name, spec, thresholds, typer.echo) for name, spec in parts.items()}
        except InputError as e:
            raise InputError(e.problem, e.path or views_json) from None
        for t in thresholds:
            per = {n: d.get(t) for n, d in decisions.items()}
            if any(v is None for v in per.values()):
                continue
            verdict = "match" if all(per.values()) else "no match"
            detail = ", ".join(f"{n}: {'match' if v else 'no match'}" for n, v in per.items())
            typer.echo(f"threshold {t:g}: {verdict}" + (f" ({detail})" if len(per) > 1 else ""))

    go()


def _draw(rgb: np.ndarray, pts: np.ndarray, colour=(255, 40, 40)) -> None:
    H, W = rgb.shape[:2]
    x, y = np.rint(pts[:, 0]).astype(int), np.rint(pts[:, 1]).astype(int)
    ok = (x >= 0) & (x < W) & (y >= 0) & (y < H)
    rgb[y[ok], x[ok]] = colour


@image_app.command("hough")
def hough(image: Path = typer.Argument(..., help="Image file (PNG, JPEG, ...)."),
          shape: str = typer.Option("lines", help="lines or circles."),
          out: Path = typer.Option(..., help="PNG with the detections drawn."),
          count: int = typer.Option(10, help="Most detections to keep."),
          radii: str = typer.Option("10:60", help="Circles: radius range MIN:MAX in pixels."),
          threshold: float = typer.Option(0.2, help="Edge threshold, share of the largest gradient."),
          orientation: bool = typer.Option(False, help="Lines: vote only near each edge's gradient direction."),
          magnitude: bool = typer.Option(False, help="Lines: weigh votes by gradient magnitude."),
          ):
    """Hough lines (x cos t - y sin t = d) or circles; prints them and draws them on the image."""
    @guard
    def go():
        from PIL import Image, UnidentifiedImageError

        from ..io.depth import write_png
        from .hough import hough_circles, hough_lines

        if shape not in ("lines", "circles"):
            raise InputError(f"--shape takes lines or circles, got {shape!r}")
        check_file(out, "picture")
        if not image.is_file():
            raise FileNotFoundError(f"{image}: image not found")
        try:
            with Image.open(image) as im:
                rgb = np.asarray(im.convert("RGB")).copy()
        except (UnidentifiedImageError, OSError) as e:
            raise InputError(f"not a readable image ({e})", image) from None
        grey = rgb.astype(float).mean(axis=2)
        if shape == "lines":
            found = hough_lines(grey, threshold=threshold, max_lines=count, use_orientation=orientation,
                                weight_by_magnitude=magnitude)
            for ln in found:
                typer.echo(f"line d {ln.d:8.2f} px  t {ln.theta_deg:7.2f} deg  votes {ln.votes:.0f}")
                p, q = ln.points(2 * float(np.hypot(*grey.shape)))
                _draw(rgb, np.linspace(p, q, 4 * int(np.hypot(*grey.shape))))
        else:
            lo, hi = (int(v) for v in radii.split(":"))
            found = hough_circles(grey, np.arange(lo, hi + 1), threshold=threshold, max_circles=count)
            a = np.linspace(0, 2 * np.pi, 720)
            for c in found:
                typer.echo(f"circle x {c.x:8.2f}  y {c.y:8.2f}  r {c.r:6.2f} px  score {c.votes:.2f}")
                _draw(rgb, np.column_stack([c.x + c.r * np.cos(a), c.y + c.r * np.sin(a)]))
        write_png(out, rgb)
        typer.echo(f"{len(found)} {shape} -> {out}")

    go()


@image_app.command("homography")
def homography(matches_json: Path = typer.Argument(..., help='JSON: {"src": [[x, y], ...], "dst": [[x, y], ...]}.'),
               affine: bool = typer.Option(False, help="Fit an affine map instead of a homography."),
               threshold: float = typer.Option(2.0, help="RANSAC inlier distance (px)."),
               seed: int = typer.Option(0, help="RANSAC seed."),
               out: Optional[Path] = typer.Option(None, help="JSON to write H, inliers and residuals to."),
               ):
    """Homography (normalised DLT, h33 = 1) or affine map from point matches, with RANSAC and residuals."""
    @guard
    def go():
        from ..io.atomic import atomic_write_text
        from .transforms import ransac_affine, ransac_homography

        if out:
            check_file(out, "JSON")
        doc = read_json(matches_json)
        _need(doc, ("src", "dst"), matches_json, "a matches file")
        try:
            r = (ransac_affine if affine else ransac_homography)(doc["src"], doc["dst"], threshold, seed=seed)
        except InputError as e:
            raise InputError(e.problem, e.path or matches_json) from None
        typer.echo("affine" if affine else "homography")
        for row in r.H:
            typer.echo("  " + " ".join(f"{v:14.8g}" for v in row))
        typer.echo(f"inliers {int(r.inliers.sum())} of {len(r.inliers)} (within {threshold:g} px), rmse "
                   f"{r.rmse:.3f} px, {r.iterations} draws")
        if out:
            atomic_write_text(out, json.dumps({"H": r.H.tolist(), "inliers": r.inliers.tolist(),
                                               "residuals_px": r.residuals.tolist(), "rmse_px": r.rmse}, indent=1))
            typer.echo(f"written: {out}")

    go()
