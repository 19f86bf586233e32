"""`pcdet image lcm | hough | homography` on small inputs with known answers."""
import json

import numpy as np
from PIL import Image
from typer.testing import CliRunner

from pcdet.cli import app
from pcdet.image.liu_wang import CLOSET_MAIN as MAIN
from pcdet.image.transforms import apply

runner = CliRunner()


def test_lcm_prints_the_paper_coefficients_and_decides_per_threshold(tmp_path):
    """The closet's main part (Liu and Wang, Fig. 4.3 iv) with a check point built from the fitted combination
    plus 0.3 of error in x: a match at threshold 0.6, none at 0.2."""
    pts = [[-2.0, 0.8], [0.3, -0.8], [1.7, -1.3], [-0.2, -2.4]]
    check_views = [[[0.5, 0.5]], [[0.4, 0.6]], [[0.3, 0.7]]]
    cx = -1.12 * 0.5 + 1.78 * 0.4 + 0.31 * 0.3 + 0.05 + 0.3
    cy = -0.32 * 0.5 + 0.09 * 0.6 + 1.21 * 0.7 + 0.03
    doc = {"views": MAIN, "points": pts, "check": {"views": check_views, "points": [[cx, cy]]},
           "thresholds": [0.2, 0.6]}
    (tmp_path / "v.json").write_text(json.dumps(doc))
    r = runner.invoke(app, ["image", "lcm", str(tmp_path / "v.json")])
    assert r.exit_code == 0, r.output
    assert "-1.121" in r.output and "1.778" in r.output and "1.213" in r.output
    assert "threshold 0.2: no match" in r.output and "threshold 0.6: match" in r.output


def test_hough_circles_draws_and_lists(tmp_path):
    yy, xx = np.mgrid[0:120, 0:160]
    img = (((xx - 80) ** 2 + (yy - 60) ** 2) < 30 ** 2).astype(np.uint8) * 200
    Image.fromarray(img).save(tmp_path / "c.png")
    r = runner.invoke(app, ["image", "hough", str(tmp_path / "c.png"), "--shape", "circles", "--radii", "20:40",
                            "--out", str(tmp_path / "o.png")])
    assert r.exit_code == 0, r.output
    assert "circle x    80.00  y    60.00" in r.output
    drawn = np.asarray(Image.open(tmp_path / "o.png"))
    assert drawn.shape == (120, 160, 3) and (drawn[..., 0] == 255).sum() > 100


def test_homography_from_matches_json(tmp_path, rng):
    H = np.array([[1.1, 0.05, 12.0], [-0.03, 0.95, -7.0], [1e-4, 2e-4, 1.0]])
    src = rng.uniform(0, 400, (40, 2))
    dst = apply(H, src)
    dst[:10] += 50.0  # a quarter are wrong
    (tmp_path / "m.json").write_text(json.dumps({"src": src.tolist(), "dst": dst.tolist()}))
    r = runner.invoke(app, ["image", "homography", str(tmp_path / "m.json"), "--out", str(tmp_path / "h.json")])
    assert r.exit_code == 0, r.output
    out = json.loads((tmp_path / "h.json").read_text())
    assert np.allclose(out["H"], H, atol=1e-6) and sum(out["inliers"]) == 30


def test_bad_inputs_give_one_error_line(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    r = runner.invoke(app, ["image", "homography", str(tmp_path / "bad.json")])
    assert r.exit_code != 0 and "not valid JSON" in r.output
    r = runner.invoke(app, ["image", "hough", str(tmp_path / "missing.png"), "--out", str(tmp_path / "o.png")])
    assert r.exit_code != 0 and "not found" in r.output
    # JSON of the wrong shape: the file and what it lacks, no traceback
    (tmp_path / "v.json").write_text('{"views": [[[0, 0], [1, 0], [0, 1], [1, 1]]], "points": [[0, 0]]}')
    r = runner.invoke(app, ["image", "homography", str(tmp_path / "v.json")])
    assert r.exit_code != 0 and "v.json: a matches file needs 'src', 'dst'" in r.output and "Traceback" not in r.output
    r = runner.invoke(app, ["image", "lcm", str(tmp_path / "v.json")])
    assert r.exit_code != 0 and "v.json: the linear combination method needs at least 3 model views" in r.output
