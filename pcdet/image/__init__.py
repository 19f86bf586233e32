"""Recognition from 2D views (the seed documents' methods): the Linear Combination Method of Liu and Wang for
rigid and articulated objects, 2D affine and homography estimation with RANSAC, Hough transforms for lines,
circles and arbitrary shapes, Hough voting of keypoint matches, image feature points, and PnP."""
from .lcm import ArticulatedModel, LinearCombination
from .transforms import fit_affine, fit_homography, ransac_affine, ransac_homography

__all__ = ["ArticulatedModel", "LinearCombination", "fit_affine", "fit_homography", "ransac_affine",
           "ransac_homography"]
