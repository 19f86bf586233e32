"""Overlay pictures: the detection's silhouette is tinted, the rest of the picture only dimmed."""
import numpy as np

from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detection
from pcdet.verify import render_model
from pcdet.viz import colorize_depth, overlay


def test_overlay_tints_exactly_the_silhouette(synth_small, library):
    ds = BopDataset(synth_small)
    img = ds.images[0]
    f = ds.frame(img)
    g = ds.gt(img)[0]
    m = library.by_id(g["obj_id"])
    det = Detection(m.name, m.obj_id, 0.9, g["T_cam_model"], 10, 1.0, 0.001, 0.8)
    pic = overlay(f, [det], library)
    mask = render_model(m, g["T_cam_model"], f.camera) > 0
    dimmed = (f.rgb.astype(np.float32) * 0.6).astype(np.uint8)
    changed = np.any(pic != dimmed, axis=2)
    assert pic.shape == f.rgb.shape and pic.dtype == np.uint8
    assert changed[mask].mean() > 0.95  # the silhouette is tinted
    from scipy.ndimage import binary_dilation

    far = ~binary_dilation(mask, iterations=20)  # away from the outline and the label box
    ys, xs = np.nonzero(mask)
    far[max(ys.min() - 14, 0):ys.min() + 1, xs.min():xs.min() + 200] = False
    assert not changed[far].any()


def test_colorize_depth_near_warm_far_cool_invalid_black():
    d = np.tile(np.linspace(0.5, 2.0, 100, dtype=np.float32), (10, 1))
    d[:, :5] = 0
    c = colorize_depth(d).astype(int)
    assert (c[:, :5] == 0).all()
    near, far = c[0, 10], c[0, 99]
    assert near[0] > near[2] and far[2] > far[0]  # red over blue near, blue over red far
