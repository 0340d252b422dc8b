"""Tests of the training package on a tiny synthetic dataset (python -m unittest discover -s train/tests -t .)."""
import json
import math
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import torch

from train import losses
from train.depth_centre import centre_fof, centring_shift, fof_centroid_z, fof_depth_range, shift_columns, shift_fof
from train.dataset import R2Dataset, downsample_view, view_angle_deg
from train.fit import R2HumanNet, decode_occupancy
from train.geometry import (back_weight, box_radii, linear_to_srgb, side_image, side_weight, source_axis, srgb_to_linear,
                            transfer, visibility, warp_rgb)
from train.nets import TIERS, Decoder, Encoder, FofNet, UNet, zmap_encoding
from train.synth import fof_from_intervals, orbit_view_from_world, write_dataset

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_DATA = None


def data():
    """One shared synthetic dataset: 4 subjects (1 held out), 3 views, 32 px, N = 8."""
    global _DATA
    if _DATA is None:
        _DATA = tempfile.mkdtemp(prefix="r2h_synth_")
        write_dataset(_DATA, subjects=4, views=3, res=32, fof_n=8, seed=1, test=1)
    return _DATA


def batch(ds, i=0):
    return {k: v[None] for k, v in ds[i].items()}


class DatasetTest(unittest.TestCase):
    def test_items_follow_the_contract(self):
        ds = R2Dataset(data(), "train")
        self.assertEqual((len(ds), ds.fof_n, ds.res), (3, 8, 32))
        b = ds[0]
        self.assertEqual(tuple(b["src_image"].shape), (3, 32, 32))
        self.assertEqual(tuple(b["src_fof"].shape), (8, 32, 32))
        m = b["src_mask"][0] > 0
        # Premultiplied: background exactly -1, the person inside [-1, 1].
        self.assertTrue(torch.all(b["src_image"][:, ~m] == -1))
        self.assertTrue(b["src_image"].min() >= -1 and b["src_image"].max() <= 1)
        n = b["ref_normals"].norm(dim=0)
        self.assertTrue(torch.allclose(n[b["ref_mask"][0] > 0], torch.ones(1), atol=1e-4))
        self.assertEqual(R2Dataset(data(), "test").subjects, ["subject_0003"])

    def test_downsampling_keeps_depth_and_normals_meaningful(self):
        ds = R2Dataset(data(), "train", resolution=16)
        full = R2Dataset(data(), "train")
        self.assertEqual(tuple(ds[0]["src_image"].shape), (3, 16, 16))
        a, b = ds[0]["src_fof"], full[0]["src_fof"]
        self.assertTrue(torch.allclose(a, b.view(8, 16, 2, 16, 2).mean((2, 4)), atol=1e-5))
        rgba = np.zeros((4, 4, 4), np.float32)
        depth = -np.ones((4, 4), np.float32)
        depth[0, 0], depth[0, 1] = 0.2, 0.4
        rgba[0, 0] = [1, 0, 0, 1]
        normal = np.zeros((4, 4, 3), np.float32)
        normal[0, 0] = normal[0, 1] = [0, 0, 1]
        r, d, n = downsample_view(rgba, depth, normal, 2)
        self.assertAlmostEqual(float(d[0, 0]), 0.3, places=6)  # mean over foreground sub-pixels only
        self.assertEqual(float(d[1, 1]), -1.0)
        self.assertAlmostEqual(float(r[0, 0, 3]), 0.25)
        self.assertAlmostEqual(float(r[0, 0, 0]), 1.0)  # straight colour survives premultiplied averaging
        self.assertTrue(np.allclose(n[0, 0], [0, 0, 1]))

    def test_view_angle(self):
        self.assertAlmostEqual(view_angle_deg(np.eye(4)), 0.0)
        self.assertAlmostEqual(view_angle_deg(orbit_view_from_world(90, 0)), 90.0, places=4)
        self.assertAlmostEqual(view_angle_deg(orbit_view_from_world(180, 0)), 180.0, places=4)


class GeometryTest(unittest.TestCase):
    def test_identity_transfer_is_pixel_centres_and_depth(self):
        depth = torch.full((1, 1, 4, 4), -1.0)
        depth[0, 0, 1, 2] = 0.25
        eye, half = torch.eye(4)[None], torch.ones(1, 2)
        grid, z, mask = transfer(depth, eye, half, eye, half)
        self.assertEqual(float(mask.sum()), 1.0)
        # col 2, row 1 of 4: x = 2.5/2 - 1 = 0.25, grid y = -(1 - 1.5/2) = -0.25.
        self.assertTrue(torch.allclose(grid[0, 1, 2], torch.tensor([0.25, -0.25])))
        self.assertAlmostEqual(float(z[0, 0, 1, 2]), 0.25)
        self.assertEqual(float(z[0, 0, 0, 0]), 0.0)

    def test_quarter_turn_maps_depth_to_source_x(self):
        # A view rotated by yaw 90 deg: its view z axis is world +-x, so the source x of a pixel is +-its depth.
        vfw = torch.tensor(orbit_view_from_world(90, 0), dtype=torch.float32)[None]
        depth = torch.full((1, 1, 2, 2), 0.5)
        grid, z, _ = transfer(depth, vfw, torch.ones(1, 2), torch.eye(4)[None], torch.ones(1, 2))
        world = torch.linalg.inv(vfw[0]) @ torch.tensor([-0.5, 0.5, 0.5, 1.0])
        self.assertTrue(torch.allclose(grid[0, 0, 0], torch.stack([world[0], -world[1]]), atol=1e-6))
        self.assertAlmostEqual(float(z[0, 0, 0, 0]), float(world[2]), places=6)
        self.assertAlmostEqual(abs(float(world[0])), 0.5, places=6)

    def test_visibility_same_view_all_and_opposite_views_little(self):
        ds = R2Dataset(data(), "train")
        b = batch(ds)
        _, vis = visibility(b["ref_depth"], b["ref_view_from_world"], b["ref_half"],
                            b["ref_depth"], b["ref_view_from_world"], b["ref_half"])
        self.assertEqual(float(vis.sum()), float((b["ref_depth"] > -1).sum()))
        # The source view against the back view of the same body: almost nothing is visible in both.
        from train.synth import render
        name = ds.subjects[0]
        with open(os.path.join(data(), name, "subject.json")) as f:
            subject = json.load(f)["subject"]
        back = torch.tensor(orbit_view_from_world(180, 0), dtype=torch.float32)[None]
        _, d_back, _, _ = render(subject, back[0].double().numpy(), 32)
        d_src = torch.from_numpy(np.load(os.path.join(data(), name, "source_depth.npy")))[None, None]
        d_back = torch.from_numpy(d_back)[None, None]
        _, vis = visibility(d_back, back, torch.ones(1, 2), d_src, torch.eye(4)[None], torch.ones(1, 2))
        self.assertLess(float(vis.sum()), 0.1 * float((d_back > -1).sum()))
        # ... while a small turn keeps most of it visible.
        side = torch.tensor(orbit_view_from_world(20, 0), dtype=torch.float32)[None]
        _, d_side, _, _ = render(subject, side[0].double().numpy(), 32)
        d_side = torch.from_numpy(d_side)[None, None]
        _, vis = visibility(d_side, side, torch.ones(1, 2), d_src, torch.eye(4)[None], torch.ones(1, 2))
        self.assertGreater(float(vis.sum()), 0.6 * float((d_side > -1).sum()))


class WarpRgbTest(unittest.TestCase):
    def test_srgb_conversions_match_the_rust_formulas(self):
        v = torch.tensor([0.0, 0.02, 0.04045, 0.5, 1.0, 1.5, -0.2])
        lin = srgb_to_linear(v)
        want = [0.0, 0.02 / 12.92, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0, 1.0, 0.0]
        self.assertTrue(torch.allclose(lin, torch.tensor(want), atol=1e-7), lin)
        x = torch.linspace(0, 1, 101)
        self.assertTrue(torch.allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-5))
        self.assertAlmostEqual(float(linear_to_srgb(torch.tensor(0.002))), 0.002 * 12.92, places=7)

    def test_identity_view_gives_straight_colour_and_zero_outside(self):
        h = w = 8
        mask = torch.zeros(1, 1, h, w)
        mask[..., 2:6, 3:7] = 1
        srgb = torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(1))
        lin = srgb_to_linear(srgb) * mask
        depth = torch.where(mask > 0, torch.tensor(0.1), torch.tensor(-1.0))
        eye, half = torch.eye(4)[None], torch.ones(1, 2)
        grid, _, tmask = transfer(depth, eye, half, eye, half)
        rgb, known = warp_rgb(lin, mask, grid, tmask)
        self.assertTrue(torch.equal(known, mask))
        self.assertTrue(torch.allclose(rgb, (srgb * 2 - 1) * mask, atol=1e-5))

    def test_silhouette_edge_is_not_darkened_and_far_outside_is_unknown(self):
        # A white square; a target pixel looking up exactly between the last inside and the first outside
        # column gets white (mask-aware), not grey; one looking far outside the square is unknown (0).
        h = w = 8
        mask = torch.zeros(1, 1, h, w)
        mask[..., :, :4] = 1
        lin = mask.expand(1, 3, h, w).clone()
        # grid x for the edge between columns 3 and 4 is 0; y of row 3's centre is -(1 - 3.5/4) = -0.125.
        grid = torch.tensor([[[[0.0, -0.125], [0.9, -0.125], [-3.0, 0.0]]]])
        tmask = torch.ones(1, 1, 1, 3)
        rgb, known = warp_rgb(lin, mask, grid, tmask)
        self.assertTrue(torch.allclose(rgb[0, :, 0, 0], torch.ones(3), atol=1e-5), rgb)
        self.assertEqual(known[0, 0, 0].tolist(), [1.0, 0.0, 0.0])
        self.assertEqual(rgb[0, :, 0, 1:].abs().sum().item(), 0.0)

    def test_back_weight_and_source_axis_match_the_rust_formulas(self):
        # src/pipeline/warp.rs: smoothstep(0, 0.3, -n . axis); axis = the source camera's +z in target view space.
        eye = torch.eye(4)[None]
        self.assertTrue(torch.allclose(source_axis(eye, eye), torch.tensor([[0.0, 0.0, 1.0]])))
        behind = torch.tensor(orbit_view_from_world(180.0, 0.0), dtype=torch.float32).reshape(1, 4, 4)
        self.assertTrue(torch.allclose(source_axis(behind, eye), torch.tensor([[0.0, 0.0, -1.0]]), atol=1e-6))
        axis = torch.tensor([[0.0, 0.0, 1.0]])
        s = math.sqrt(1 - 0.15 ** 2)
        normals = torch.tensor([[0, 0, 1], [0, 0, -1], [1, 0, 0], [s, 0, -0.15], [float("nan"), 0, 0]],
                               dtype=torch.float32).T.reshape(1, 3, 1, 5)
        self.assertTrue(torch.allclose(back_weight(normals, axis)[0, 0, 0], torch.tensor([0.0, 1.0, 0.0, 0.5, 0.0]),
                                       atol=1e-6))

    @staticmethod
    def identity_lookup(h, w, rows, cols, seed):
        """A random photo and back image (linear, premultiplied) on a box mask, and the identity view's flow."""
        mask = torch.zeros(1, 1, h, w)
        mask[..., rows, cols] = 1
        g = torch.Generator().manual_seed(seed)
        photo, behind = (srgb_to_linear(torch.rand(1, 3, h, w, generator=g)) * mask for _ in range(2))
        depth = torch.where(mask > 0, torch.tensor(0.1), torch.tensor(-1.0))
        eye, half = torch.eye(4)[None], torch.ones(1, 2)
        grid, _, tmask = transfer(depth, eye, half, eye, half)
        return mask, photo, behind, grid, tmask

    def test_back_lookup_blends_the_photo_and_the_back_image_in_linear_light(self):
        h = w = 8
        mask, photo, behind, grid, tmask = self.identity_lookup(h, w, slice(2, 6), slice(3, 7), 2)
        alone, _ = warp_rgb(photo, mask, grid, tmask)
        for weight, want in [(0.0, photo), (1.0, behind), (0.25, 0.75 * photo + 0.25 * behind)]:
            rgb, known = warp_rgb(photo, mask, grid, tmask, behind, torch.full((1, 1, h, w), weight))
            self.assertTrue(torch.equal(known, mask))
            self.assertTrue(torch.allclose(rgb, (linear_to_srgb(want) * 2 - 1) * mask, atol=1e-5), weight)
        self.assertTrue(torch.allclose(warp_rgb(photo, mask, grid, tmask, behind, torch.zeros(1, 1, h, w))[0], alone))


    def test_side_weight_and_box_radii_match_the_rust_formulas(self):
        # src/pipeline/warp.rs: 1 - smoothstep(0, 0.5, |n . axis| / |n_z|) (the same cases as
        # `cargo test --lib side_weight_in_closed_form`); the image crate's fast_blur boxes.
        s = 1 / math.sqrt(1 + 0.25 ** 2)
        normals = torch.tensor([[0, 0, 1], [0, 0, -1], [0.6, 0, 0.8], [1, 0, 0], [0, 1, 0], [0.25 * s, 0, s],
                                [-0.25 * s, 0, s], [float("nan"), 0, 0], [0, 0, 0]],
                               dtype=torch.float32).T.reshape(1, 3, 1, 9)
        side_view = torch.tensor([[1.0, 0.0, 0.0]])
        self.assertTrue(torch.allclose(side_weight(normals, side_view)[0, 0, 0],
                                       torch.tensor([1.0, 1.0, 0.0, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0]), atol=1e-6))
        # From the photo's own direction: the sharp photo everywhere.
        own_view = torch.tensor([[0.0, 0.0, 1.0]])
        self.assertTrue(torch.all(side_weight(normals, own_view) == 0))
        # sigma 4 (512 px): boxes 7, 7, 9 -> radii 3, 3, 5 (the crate rounds each radius up to an odd one).
        self.assertEqual(box_radii(4.0), [3, 3, 5])
        self.assertEqual(box_radii(2.0), [1, 1, 3])
        self.assertEqual(box_radii(1.0), [1, 1, 1])

    def test_side_image_is_three_box_passes_inside_the_mask(self):
        # A step from white to black at column 64 of a 128-wide image (sigma 1 px: three boxes of 3): the kernel
        # [1, 3, 6, 7, 6, 3, 1] / 27, so columns 61..66 are 26, 23, 17, 10, 4, 1 / 27. The same numbers in
        # `cargo test --lib side_images_are_three_box_passes`.
        h, w = 8, 128
        linear = torch.zeros(1, 3, h, w)
        linear[..., :64] = 1
        side = side_image(linear, torch.ones(1, 1, h, w))
        want = torch.tensor([27, 26, 23, 17, 10, 4, 1, 0]) / 27
        self.assertTrue(torch.allclose(side[0, :, :, 60:68], want.expand(3, h, 8), atol=1e-5), side[0, 0, 0, 58:70])
        # Mask-aware: a disc of one colour on black stays that colour to its outline, and nothing outside.
        yy, xx = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
        mask = (((yy - 15.5) ** 2 + (xx - 15.5) ** 2) < 100).float()[None, None]
        colour = torch.tensor([0.2, 0.5, 0.9])[None, :, None, None]
        side = side_image(colour * mask, mask)
        self.assertTrue(torch.allclose(side, colour * mask, atol=1e-5))

    def test_side_lookup_blends_the_side_images_by_their_weight(self):
        h = w = 16
        mask, photo, behind, grid, tmask = self.identity_lookup(h, w, slice(3, 13), slice(4, 12), 3)
        side_photo, side_behind = side_image(photo, mask), side_image(behind, mask)
        back = torch.full((1, 1, h, w), 0.25)
        sharp, _ = warp_rgb(photo, mask, grid, tmask, behind, back)
        blurred, _ = warp_rgb(side_photo, mask, grid, tmask, side_behind, back)
        for weight in (0.0, 0.5, 1.0):
            rgb, known = warp_rgb(photo, mask, grid, tmask, behind, back,
                                  (side_photo, side_behind, torch.full((1, 1, h, w), weight)))
            self.assertTrue(torch.equal(known, mask))
            if weight in (0.0, 1.0):
                self.assertTrue(torch.allclose(rgb, sharp if weight == 0 else blurred, atol=1e-5), weight)
            else:
                # The blend is in linear light, before the sRGB encoding.
                lin = lambda x: srgb_to_linear((x + 1) / 2)
                self.assertTrue(torch.allclose(lin(rgb) * mask, (lin(sharp) + lin(blurred)) / 2 * mask, atol=1e-5))
        # The side images differ from the photo: the test sees the blend.
        self.assertGreater((sharp - blurred).abs().max().item(), 0.05)


class FofTest(unittest.TestCase):
    def test_single_interval_coefficients_and_decode(self):
        z_in, z_out = -0.3, 0.5
        iv = [(np.array([[z_in]]), np.array([[z_out]]), np.array([[True]]))]
        c = fof_from_intervals(iv, 32)
        self.assertAlmostEqual(float(c[0, 0, 0]), z_out - z_in, places=5)
        k = 3
        want = (math.sin(k * math.pi * (z_out + 1) / 2) - math.sin(k * math.pi * (z_in + 1) / 2)) / (k * math.pi / 2)
        self.assertAlmostEqual(float(c[0, 0, k]), want, places=5)
        occ = decode_occupancy(torch.from_numpy(c).permute(2, 0, 1)[None], 64)[0, :, 0, 0]
        s = (torch.arange(64) + 0.5) / 64 * 2 - 1  # z of each sample
        inside = (s > z_in + 0.1) & (s < z_out - 0.1)
        outside = (s < z_in - 0.1) | (s > z_out + 0.1)
        self.assertTrue(torch.all(occ[inside] > 0.8) and torch.all(occ[outside] < 0.2), occ)

    def test_overlapping_intervals_are_merged(self):
        iv = [(np.array([[-0.5]]), np.array([[0.2]]), np.array([[True]])),
              (np.array([[0.0]]), np.array([[0.4]]), np.array([[True]])),
              (np.array([[0.6]]), np.array([[0.7]]), np.array([[True]]))]
        c = fof_from_intervals(iv, 8)
        self.assertAlmostEqual(float(c[0, 0, 0]), 0.9 + 0.1, places=5)


def interval_fof(lo, hi, n=32):
    """[1,N,H,W] FOF of one interval [lo, hi] per pixel (arrays of the same shape; lo >= hi: empty)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = fof_from_intervals([(lo, hi, hi > lo)], n)
    return torch.from_numpy(c).permute(2, 0, 1)[None].float()


def crossings(fof, samples=2048):
    """z of the first and last 0.5 crossing of pixel (0, 0) of a [1,N,H,W] FOF."""
    occ = decode_occupancy(fof, samples)[0, :, 0, 0]
    inside = (occ >= 0.5).nonzero()[:, 0].float()
    z = 2.0 * (inside + 0.5) / samples - 1.0
    return float(z.min()), float(z.max())


class DepthCentreTest(unittest.TestCase):
    """train/depth_centre.py against the closed forms of src/geometry/depth_centre.rs."""

    def test_centroid_of_intervals_is_their_volume_weighted_middle(self):
        # Two columns: [-0.6, -0.2] (volume 0.4, middle -0.4) and [0.1, 0.9] (0.8, 0.5): centroid (0.4 * -0.4 +
        # 0.8 * 0.5) / 1.2 = 0.2.
        fof = interval_fof([[-0.6, 0.1]], [[-0.2, 0.9]])
        self.assertAlmostEqual(float(fof_centroid_z(fof)[0]), 0.2, places=2)
        self.assertTrue(math.isnan(float(fof_centroid_z(torch.zeros(1, 32, 2, 2))[0])))
        # The mask leaves the second column out.
        mask = torch.tensor([[[[1.0, 0.0]]]])
        self.assertAlmostEqual(float(fof_centroid_z(fof, mask)[0]), -0.4, places=2)

    def test_shift_moves_an_interval_and_keeps_its_volume(self):
        fof = interval_fof([[-0.5]], [[0.1]])
        for dz in (0.3, -0.35, 0.0):
            moved = shift_fof(fof, torch.tensor([dz]))
            lo, hi = crossings(moved)
            self.assertAlmostEqual(lo, -0.5 + dz, delta=0.01)
            self.assertAlmostEqual(hi, 0.1 + dz, delta=0.01)
            self.assertAlmostEqual(float(moved[0, 0, 0, 0]), float(fof[0, 0, 0, 0]), places=5)
        # There and back: the projection onto the N stored terms loses a little (the shifted truncated series is
        # not itself truncated), 1.5e-3 of coefficients of order 1 at N = 32.
        back = shift_fof(shift_fof(fof, torch.tensor([0.2])), torch.tensor([-0.2]))
        self.assertLess(float((back - fof).abs().max()), 3e-3)

    def test_centring_shift_rule(self):
        t = lambda *v: torch.tensor(v, dtype=torch.float32)
        # Plain: the centroid to 0.
        self.assertAlmostEqual(float(centring_shift(t(0.3), t(-0.2), t(0.8))[0]), -0.3, places=6)
        # Limited: -0.5 would put z_min -0.7 at -1.2; the smallest shift keeping it inside is -0.3.
        self.assertAlmostEqual(float(centring_shift(t(0.5), t(-0.7), t(0.9))[0]), -0.3, places=6)
        # Wider than the cube: its middle to 0. NaN input: no shift.
        self.assertAlmostEqual(float(centring_shift(t(0.5), t(-1.2), t(1.0))[0]), 0.1, places=6)
        self.assertEqual(float(centring_shift(t(float("nan")), t(-0.2), t(0.3))[0]), 0.0)

    def test_centre_fof_puts_the_centroid_at_zero_and_is_differentiable(self):
        fof = interval_fof([[0.2, 0.3]], [[0.8, 0.6]]).requires_grad_(True)
        centred, dz = centre_fof(fof)
        self.assertAlmostEqual(float(fof_centroid_z(centred.detach())[0]), 0.0, delta=0.01)
        self.assertAlmostEqual(float(dz.detach()[0]), -float(fof_centroid_z(fof.detach())[0]), delta=1e-5)
        lo, hi = fof_depth_range(centred.detach())
        self.assertTrue(-1.0 <= float(lo[0]) < float(hi[0]) <= 1.0)
        centred.sum().backward()
        self.assertTrue(torch.isfinite(fof.grad).all())
        # Empty and all-zero input: unchanged, no NaN.
        zero = torch.zeros(2, 8, 3, 3)
        out, dz = centre_fof(zero)
        self.assertTrue(torch.equal(out, zero) and torch.equal(dz, torch.zeros(2)))


class PlacementTest(unittest.TestCase):
    """train/placement.py: per-column shifts, column moments in closed form, the untrained net is `body-placed`."""

    def test_shift_columns_moves_each_column_by_its_own_shift(self):
        fof = interval_fof([[-0.5, -0.2]], [[0.1, 0.4]])
        dz = torch.tensor([[[[0.3, -0.25]]]])
        moved = shift_columns(fof, dz)
        for col, (lo, hi, d) in enumerate([(-0.5, 0.1, 0.3), (-0.2, 0.4, -0.25)]):
            a, b = crossings(moved[..., col:col + 1])
            self.assertAlmostEqual(a, lo + d, delta=0.01)
            self.assertAlmostEqual(b, hi + d, delta=0.01)
        # The same shift everywhere is shift_fof.
        same = shift_columns(fof, torch.full((1, 1, 1, 2), 0.2))
        self.assertLess(float((same - shift_fof(fof, torch.tensor([0.2]))).abs().max()), 1e-5)

    def test_column_length_and_centroid_and_about_centroid(self):
        from train.placement import about_centroid, column_length_and_centroid
        # [-0.6, -0.2] (length 0.4, middle -0.4), [0.1, 0.9] (0.8, 0.5), an empty column.
        fof = interval_fof([[-0.6, 0.1, 0.0]], [[-0.2, 0.9, 0.0]])
        length, centroid, cols = column_length_and_centroid(fof)
        self.assertEqual(cols[0, 0, 0].tolist(), [True, True, False])
        for got, want in zip(length[0, 0, 0].tolist(), [0.4, 0.8, 0.0]):
            self.assertAlmostEqual(got, want, delta=0.01)
        for got, want in zip(centroid[0, 0, 0].tolist(), [-0.4, 0.5, 0.0]):
            self.assertAlmostEqual(got, want, delta=0.01)
        # About the volume-weighted centroid 0.2: -0.6, 0.3, and 0 where empty.
        for got, want in zip(about_centroid(length, centroid, cols)[0, 0, 0].tolist(), [-0.6, 0.3, 0.0]):
            self.assertAlmostEqual(got, want, delta=0.01)

    def test_untrained_net_is_body_placed_and_training_moves_it(self):
        from train.placement import PLACEMENT_WEIGHT, PlacementNet, base_placement
        # The prior: two columns on the centre plane; the body puts the first 0.4 ahead of the second.
        # On an 8 x 8 grid (the UNet's stride), the columns in row 0, the rest empty.
        def grid(lo, hi):
            a, b = np.zeros((8, 8)), np.zeros((8, 8))
            a[0, :3], b[0, :3] = lo, hi
            return interval_fof(a, b)

        prior = grid([-0.2, -0.2, 0.0], [0.2, 0.2, 0.0])
        body = grid([0.1, -0.3, 0.0], [0.3, -0.1, 0.0])
        net = PlacementNet("tiny")
        with torch.no_grad():
            shift = net(body, prior)
        # Body centroids 0.2 and -0.2 about their mean 0: shifts 0.5 * (+-0.2); the empty column stays.
        for got, want in zip(shift[0, 0, 0, :3].tolist(), [PLACEMENT_WEIGHT * 0.2, -PLACEMENT_WEIGHT * 0.2, 0.0]):
            self.assertAlmostEqual(got, want, delta=0.01)
        self.assertEqual(float(shift[0, 0, 1:].abs().max()), 0.0)
        self.assertLess(float((net.place(body, prior) - base_placement(body, prior)).abs().max()), 1e-6)
        (net.place(body, prior) - 0.3).abs().mean().backward()
        self.assertGreater(float(net.net.out.weight.grad.abs().sum()), 0.0)
        # Empty and NaN-free: all-zero inputs give a zero shift.
        with torch.no_grad():
            zero = net(torch.zeros(1, 32, 8, 8), torch.zeros(1, 32, 8, 8))
        self.assertTrue(torch.equal(zero, torch.zeros_like(zero)))


class LossTest(unittest.TestCase):
    def test_masked_l1_ssim_and_perceptual(self):
        x = torch.rand(1, 3, 16, 16) * 2 - 1
        m = torch.zeros(1, 1, 16, 16)
        m[..., 4:12, 4:12] = 1
        y = x.clone()
        y[..., :2, :] += 5  # differences outside the mask do not count
        self.assertAlmostEqual(float(losses.masked_l1(y, x, m)), 0.0)
        self.assertAlmostEqual(float(losses.masked_l1(x + 0.5 * m, x, m)), 0.5, places=6)
        self.assertTrue(torch.allclose(losses.ssim_map((x + 1) / 2, (x + 1) / 2), torch.ones(1), atol=1e-4))
        self.assertAlmostEqual(float(losses.perceptual(y, x, m)), 0.0, places=4)
        self.assertGreater(float(losses.perceptual(-x, x, m)), 0.5)

    def test_ground_truth_views_are_consistent(self):
        # Exact renders of one textured body from two views agree where Eq. 9 says both see the surface.
        from train.synth import render
        with open(os.path.join(data(), "subject_0000", "subject.json")) as f:
            subject = json.load(f)["subject"]
        b = {}
        for name, yaw in (("ref", 0.0), ("mv", 20.0)):
            m = orbit_view_from_world(yaw, 5)
            rgba, d, _, _ = render(subject, m, 64)
            b[name + "_rgb"] = torch.from_numpy(rgba[..., :3] * 2 - 1).permute(2, 0, 1)[None].float()
            b[name + "_depth"] = torch.from_numpy(d)[None, None]
            b[name + "_mask"] = torch.from_numpy((d > -1).astype(np.float32))[None, None]
            b[name + "_view_from_world"] = torch.tensor(m, dtype=torch.float32)[None]
            b[name + "_half"] = torch.ones(1, 2)
        l_gt, frac = losses.consistency(b["ref_rgb"], b["mv_rgb"], b)
        self.assertGreater(float(frac), 0.8)
        l_bad, _ = losses.consistency(b["ref_rgb"], -b["mv_rgb"], b)
        self.assertLess(float(l_gt), 0.06)
        self.assertGreater(float(l_bad), 8 * float(l_gt))


def colour_batch(seed):
    """Two items of an 8x8 renderer batch for the colour augmentations: the mask (a 4x4 square), the photo's sRGB
    colours, and the batch (photo premultiplied in linear light and as the encoder's input, a back image, targets
    equal to the photo)."""
    h = w = 8
    mask = torch.zeros(2, 1, h, w)
    mask[..., 2:6, 3:7] = 1
    g = torch.Generator().manual_seed(seed)
    srgb = torch.rand(2, 3, h, w, generator=g)
    b = {"src_mask": mask, "src_linear": srgb_to_linear(srgb) * mask, "src_image": srgb * mask * 2 - 1,
         "src_back_linear": srgb_to_linear(torch.rand(2, 3, h, w, generator=g)) * mask,
         "ref_rgb": srgb * 2 - 1}
    return mask, srgb, b


class NetsTest(unittest.TestCase):
    def test_shapes_per_tier(self):
        for tier in ("tiny", "small"):
            c = TIERS[tier]["features"]
            e, d, f = Encoder(tier, 8), Decoder(tier), FofNet(tier, 8)
            with torch.no_grad():
                feats = e(torch.zeros(1, 3, 64, 64), torch.zeros(1, 8, 64, 64), torch.zeros(1, 3, 64, 64))
                self.assertEqual(tuple(feats.shape), (1, c, 16, 16))
                s = d.stride
                out = d(torch.zeros(1, c, 3 * s, 5 * s), torch.zeros(1, 1, 3 * s, 5 * s), torch.zeros(1, 3, 3 * s, 5 * s),
                        torch.zeros(1, 3, 3 * s, 5 * s))
                self.assertEqual(tuple(out.shape), (1, 3, 3 * s, 5 * s))
                self.assertEqual(tuple(f(torch.zeros(1, 3, 64, 64), torch.zeros(1, 8, 64, 64)).shape), (1, 8, 64, 64))
                plain = FofNet(tier, 8, prior=False)
                self.assertEqual(tuple(plain(torch.zeros(1, 3, 64, 64)).shape), (1, 8, 64, 64))

    def test_untrained_fof_net_is_the_prior_and_training_moves_it(self):
        f = FofNet("tiny", 8)
        g = torch.Generator().manual_seed(5)
        image, prior = torch.rand(2, 3, 32, 32, generator=g) * 2 - 1, torch.randn(2, 8, 32, 32, generator=g)
        with torch.no_grad():
            self.assertTrue(torch.equal(f(image, prior), prior))
        (f(image, prior) - 0.3).abs().mean().backward()
        self.assertGreater(float(f.net.out.weight.grad.abs().sum()), 0.0)

    def test_body_inputs_residual_base_and_checks(self):
        from train.nets import fof_net_from_checkpoint, parse_fof_inputs
        g = torch.Generator().manual_seed(6)
        image = torch.rand(1, 3, 32, 32, generator=g) * 2 - 1
        body, prior = torch.randn(1, 8, 32, 32, generator=g), torch.randn(1, 8, 32, 32, generator=g)
        f = FofNet("tiny", 8, inputs=("image", "body", "prior"), residual="body")
        first = next(m for m in f.modules() if isinstance(m, torch.nn.Conv2d))
        self.assertEqual(first.in_channels, 3 + 8 + 8)
        with torch.no_grad():
            # Untrained: exactly the body base, whatever the prior says.
            self.assertTrue(torch.equal(f(image, body, prior), body))
            self.assertTrue(torch.equal(FofNet("tiny", 8, inputs=("image", "body", "prior"), residual="prior")(
                image, body, prior), prior))
            self.assertTrue(torch.equal(FofNet("tiny", 8, inputs=("image", "body"))(image, body), body))
        with self.assertRaises(ValueError):
            f(image, body)
        # Geometry only (no photo): the FOF inputs alone, the residual base returned untrained.
        self.assertEqual(parse_fof_inputs("body, prior"), ("body", "prior"))
        geo = FofNet("tiny", 8, inputs=("body", "prior"), residual="prior")
        self.assertEqual(next(m for m in geo.modules() if isinstance(m, torch.nn.Conv2d)).in_channels, 8 + 8)
        with torch.no_grad():
            self.assertTrue(torch.equal(geo(body, prior), prior))
        with self.assertRaises(ValueError):
            geo(image, body, prior)
        with self.assertRaises(ValueError):
            FofNet("tiny", 8, inputs=("image", "body"), residual="image")
        for bad in ("body,image", "image,body,body", "image,depth", "", "prior,prior"):
            with self.assertRaises(ValueError):
                parse_fof_inputs(bad)
        with self.assertRaises(ValueError):
            FofNet("tiny", 8, inputs=("image", "body"), residual="prior")
        # Checkpoints: new ones name inputs and residual; old ones only `prior`.
        new = fof_net_from_checkpoint({"tier": "tiny", "fof_n": 8, "inputs": ["image", "body"], "residual": "body"})
        self.assertEqual((new.inputs, new.residual), (("image", "body"), "body"))
        old = fof_net_from_checkpoint({"tier": "tiny", "fof_n": 8, "prior": True})
        self.assertEqual((old.inputs, old.residual), (("image", "prior"), "prior"))
        plain = fof_net_from_checkpoint({"tier": "tiny", "fof_n": 8, "prior": False})
        self.assertEqual((plain.inputs, plain.residual), (("image",), None))

    def test_body_depth_flip_mirrors_the_body_interval_front_to_back_only(self):
        import math
        from train.fit import decode_occupancy, flip_body_in_depth
        n, (a, b) = 32, (0.1, 0.3)
        k = torch.arange(1, n, dtype=torch.float64)
        c = torch.zeros(n, dtype=torch.float64)
        c[0] = 2 * (b - a)
        c[1:] = 2 * (torch.sin(k * math.pi * b) - torch.sin(k * math.pi * a)) / (k * math.pi)
        body = c.float().view(1, n, 1, 1).repeat(3, 1, 1, 1)
        prior = torch.randn(3, n, 1, 1)
        out = flip_body_in_depth({"src_body": body, "src_prior": prior}, torch.Generator().manual_seed(0), 1.0)
        occ = decode_occupancy(out["src_body"], 64)[:, :, 0, 0]
        inside = [i for i in range(64) if occ[0, i] > 0.5]
        # [0.1, 0.3] of the ray becomes [0.7, 0.9]: samples 45..57 of 64 (centres (i + 0.5) / 64).
        self.assertEqual((inside[0], inside[-1]), (45, 57))
        self.assertTrue(torch.equal(out["src_prior"], prior), "only the body FOF is mirrored")
        self.assertTrue(torch.equal(flip_body_in_depth({"src_body": body}, torch.Generator(), 0.0)["src_body"], body))

    def test_flip_batch_mirrors_every_source_tensor_of_the_same_items(self):
        from train.fit import flip_batch
        b = {k: torch.arange(2 * 2 * 3 * 4, dtype=torch.float32).view(2, 2, 3, 4) + i
             for i, k in enumerate(["src_image", "src_mask", "src_fof", "src_prior", "src_body"])}
        out = flip_batch(b, torch.Generator().manual_seed(0))
        flipped = [bool(torch.equal(out["src_image"][j], torch.flip(b["src_image"][j], dims=[-1]))) for j in range(2)]
        for k in b:
            for j in range(2):
                want = torch.flip(b[k][j], dims=[-1]) if flipped[j] else b[k][j]
                self.assertTrue(torch.equal(out[k][j], want), (k, j))

    def test_paper_decoder_sees_291_channels_plus_the_warped_photo(self):
        d = Decoder("paper")
        first = d.net.inc[0][0]
        self.assertEqual(first.in_channels, 291 + 3)
        self.assertEqual([m.out_channels for m in d.net.downs.modules() if isinstance(m, torch.nn.Conv2d)][-1], 1024)

    def test_zmap_encoding(self):
        z = torch.tensor([0.25]).view(1, 1, 1, 1)
        e = zmap_encoding(z)[0, :, 0, 0]
        self.assertEqual(e.shape[0], 32)
        self.assertAlmostEqual(float(e[0]), math.cos(math.pi * 0.25), places=6)
        self.assertAlmostEqual(float(e[16 + 3]), math.sin(4 * math.pi * 0.25), places=6)

    def test_untrained_decoder_is_the_geometric_lookup_and_training_moves_it(self):
        d = Decoder("tiny")
        g = torch.Generator().manual_seed(3)
        args = (torch.randn(2, 16, 8, 12, generator=g), torch.rand(2, 1, 8, 12, generator=g),
                torch.randn(2, 3, 8, 12, generator=g), torch.rand(2, 3, 8, 12, generator=g) * 2 - 1)
        with torch.no_grad():
            self.assertTrue(torch.equal(d(*args), args[3]))
        # The zero-initialised last convolution still receives a gradient, so the residual can be learned.
        loss = (d(*args) - 0.3).abs().mean()
        loss.backward()
        self.assertGreater(float(d.net.out.weight.grad.abs().sum()), 0.0)

    def test_colour_permutation_is_one_per_item_and_the_same_in_every_colour_image(self):
        from train.fit import COLOUR_KEYS, permute_colours
        g = torch.Generator().manual_seed(4)
        b = {k: torch.rand(16, 3, 4, 5, generator=g) for k in COLOUR_KEYS}
        b["src_mask"] = torch.rand(16, 1, 4, 5, generator=g)
        b["ref_normals"] = torch.rand(16, 3, 4, 5, generator=g)
        out = permute_colours(b, torch.Generator().manual_seed(5))
        self.assertIs(out["src_mask"], b["src_mask"])
        self.assertIs(out["ref_normals"], b["ref_normals"])
        orders = set()
        for i in range(16):
            # Which input channel each output channel is, read off the first image; every image agrees.
            order = [next(c for c in range(3) if torch.equal(out["src_image"][i, o], b["src_image"][i, c]))
                     for o in range(3)]
            self.assertEqual(sorted(order), [0, 1, 2])
            orders.add(tuple(order))
            for k in COLOUR_KEYS:
                self.assertTrue(torch.equal(out[k][i], b[k][i, order]), k)
        self.assertGreater(len(orders), 1)

    def test_colour_inversion_commutes_with_the_lookup(self):
        # Inverted in linear light, the photo's lookup is the inverted lookup, and the encoder's input and the targets
        # are the inverted colours: every item either all inverted or all as it was.
        from train.fit import invert_colours
        mask, srgb, b = colour_batch(6)
        out = invert_colours(b, torch.Generator().manual_seed(0), p=1.0)
        self.assert_recoloured(out, mask, linear_to_srgb(1 - srgb_to_linear(srgb)))
        self.assertTrue(torch.equal(invert_colours(b, torch.Generator().manual_seed(0), p=0.0)["ref_rgb"], b["ref_rgb"]))

    def test_colour_gain_commutes_with_the_lookup(self):
        # One gain per item and channel in linear light, within [0.2, 1], the same in the lookup, the encoder's input
        # and the targets; the items differ.
        from train.fit import gain_colours
        mask, srgb, b = colour_batch(7)
        linear = srgb_to_linear(srgb)
        out = gain_colours(b, torch.Generator().manual_seed(0))
        gain = out["src_linear"][:, :, 3, 4] / linear[:, :, 3, 4]
        self.assertTrue(bool(((gain >= 0.2 - 1e-6) & (gain <= 1 + 1e-6)).all()), gain)
        self.assertFalse(torch.allclose(gain[0], gain[1]))
        self.assertTrue(torch.allclose(out["src_back_linear"], b["src_back_linear"] * gain[:, :, None, None]))
        self.assert_recoloured(out, mask, linear_to_srgb(linear * gain[:, :, None, None]))

    def assert_recoloured(self, out, mask, want):
        """The targets and the encoder's input are `want` (sRGB in [0, 1]; -1 outside the mask), and the photo's lookup
        through a view onto itself gives `want` where the person is."""
        self.assertTrue(torch.allclose(out["ref_rgb"], want * 2 - 1, atol=1e-5))
        self.assertTrue(torch.allclose(out["src_image"], torch.where(mask > 0, want * 2 - 1, torch.tensor(-1.0)),
                                       atol=1e-5))
        depth = torch.where(mask > 0, torch.tensor(0.1), torch.tensor(-1.0))
        eye, half = torch.eye(4)[None].expand(2, 4, 4), torch.ones(2, 2)
        grid, _, tmask = transfer(depth, eye, half, eye, half)
        rgb, _ = warp_rgb(out["src_linear"], mask, grid, tmask)
        self.assertTrue(torch.allclose(rgb, (want * 2 - 1) * mask, atol=1e-5))

    def test_unet_stride(self):
        self.assertEqual(UNet(3, 3, [8, 8, 8], light=True).stride, 4)


class TrainExportTest(unittest.TestCase):
    def test_fit_export_and_onnx_agreement(self):
        out = tempfile.mkdtemp(prefix="r2h_run_")
        env = dict(os.environ, PYTHONPATH=ROOT)
        base = [sys.executable, "-m", "train"]
        common = ["--data", data(), "--tier", "tiny", "--resolution", "32", "--steps", "3", "--batch", "2",
                  "--log-every", "1", "--threads", "1"]
        subprocess.run(base + ["fit", *common, "--out", out], check=True, env=env, capture_output=True)
        subprocess.run(base + ["fit-fof", *common, "--out", out], check=True, env=env, capture_output=True)
        log = open(os.path.join(out, "train.log")).read()
        self.assertIn("held-out evaluation", log)
        self.assertIn("held-out FOF evaluation", log)
        self.assertIn("prior_occupancy_iou", log)
        models = os.path.join(out, "models")
        r = subprocess.run(base + ["export", "--renderer", os.path.join(out, "renderer.pt"), "--fof",
                                   os.path.join(out, "fof.pt"), "--out", models], check=True, env=env,
                           capture_output=True, text=True)
        report = json.load(open(os.path.join(models, "export_report.json")))
        self.assertLess(report["encoder"]["max_abs_diff"], 1e-3, r.stdout)
        for v in report["decoder"].values():
            self.assertLess(v["max_abs_diff"], 1e-3)
        import onnx
        m = onnx.load(os.path.join(models, "decoder.onnx"))
        meta = {p.key: p.value for p in m.metadata_props}
        self.assertEqual((meta["r2human.kind"], meta["r2human.tier"], meta["r2human.resolution"],
                          meta["r2human.fof_n"], meta["r2human.stride"]), ("decoder", "tiny", "32", "8", "4"))
        self.assertEqual(json.loads(meta["r2human.recipe"])["steps"], 3)
        self.assertEqual([i.name for i in m.graph.input], ["features", "zmap", "normals", "warped_rgb"])
        # `fit --init-from`: a model folder's weights come back exactly (fine-tuning a shipped renderer).
        from train.fit import load_onnx_weights
        trained = torch.load(os.path.join(out, "renderer.pt"))["model"]
        fresh = R2HumanNet("tiny", 8)
        self.assertEqual(load_onnx_weights(fresh, models)["steps"], 3)
        for k, v in fresh.state_dict().items():
            self.assertTrue(torch.equal(v, trained[k]), k)
        with self.assertRaisesRegex(ValueError, "another tier or FOF order"):
            load_onnx_weights(R2HumanNet("tiny", 16), models)
        tuned = os.path.join(out, "tuned")
        subprocess.run(base + ["fit", *common, "--init-from", models, "--out", tuned], check=True, env=env,
                       capture_output=True)
        self.assertEqual(torch.load(os.path.join(tuned, "renderer.pt"))["recipe"]["previous_stage"]["steps"], 3)
        self.assertLess(report["fof"]["max_abs_diff"], 1e-3)
        f = onnx.load(os.path.join(models, "fof.onnx"))
        self.assertEqual([i.name for i in f.graph.input], ["image", "prior"])
        self.assertEqual({p.key: p.value for p in f.metadata_props}["r2human.residual"], "prior")
        self.assertEqual({p.key: p.value for p in f.metadata_props}["r2human.fof_inputs"], "image,prior")
        # The reference's inputs: photo + body FOF (+ the prior), residual on the body.
        body_run = os.path.join(out, "body")
        subprocess.run(base + ["fit-fof", *common, "--inputs", "image,body,prior", "--out", body_run], check=True,
                       env=env, capture_output=True)
        log = open(os.path.join(body_run, "train.log")).read()
        self.assertIn("body_occupancy_iou", log)
        self.assertIn("residual on body", log)
        subprocess.run(base + ["export", "--fof", os.path.join(body_run, "fof.pt"), "--out", body_run], check=True,
                       env=env, capture_output=True)
        f = onnx.load(os.path.join(body_run, "fof.onnx"))
        meta = {p.key: p.value for p in f.metadata_props}
        self.assertEqual([i.name for i in f.graph.input], ["image", "body", "prior"])
        self.assertEqual((meta["r2human.fof_inputs"], meta["r2human.residual"]), ("image,body,prior", "body"))
        self.assertLess(json.load(open(os.path.join(body_run, "export_report.json")))["fof"]["max_abs_diff"], 1e-3)
        # `train eval --fof-onnx`: the exported file scores what its checkpoint scores, next to the priors, per
        # framing, on every subject (`--split all`).
        r = subprocess.run(base + ["eval", "--data", data(), "--fof", os.path.join(body_run, "fof.pt"), "--fof-onnx",
                                   f"exported={os.path.join(body_run, 'fof.onnx')}", "--split", "all"], check=True,
                           env=env, capture_output=True, text=True)
        ev = json.loads(r.stdout)["fof"]
        self.assertEqual(ev["subjects"], 4)
        self.assertAlmostEqual(ev["exported_occupancy_iou"], ev["occupancy_iou"], places=4)
        self.assertIn("prior_occupancy_iou", ev)
        self.assertEqual(sum(g["subjects"] for g in ev["by_framing"].values()), 4)
        self.assertEqual(set(next(iter(ev["per_subject"].values()))), {"net", "prior", "body", "exported"})
        bad = subprocess.run(base + ["eval", "--data", data(), "--fof-onnx", "nofile"], env=env, capture_output=True,
                             text=True)
        self.assertNotEqual(bad.returncode, 0)
        self.assertIn("expected NAME=PATH", bad.stderr)
        bad = subprocess.run(base + ["fit-fof", *common, "--inputs", "image,body", "--residual", "prior", "--out",
                                     os.path.join(out, "bad")], env=env, capture_output=True, text=True)
        self.assertNotEqual(bad.returncode, 0)
        self.assertIn("--residual prior is not one of --inputs", bad.stderr)

    def test_torchrun_two_processes(self):
        out = tempfile.mkdtemp(prefix="r2h_ddp_")
        env = dict(os.environ, PYTHONPATH=ROOT, OMP_NUM_THREADS="1")
        torchrun = os.path.join(os.path.dirname(sys.executable), "torchrun")
        r = subprocess.run([torchrun, "--standalone", "--nproc_per_node=2", "-m", "train", "fit", "--data", data(),
                            "--tier", "tiny", "--resolution", "16", "--steps", "2", "--batch", "1", "--log-every",
                            "1", "--no-eval", "--threads", "1", "--out", out], env=env, capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr[-3000:])
        log = open(os.path.join(out, "train.log")).read()
        self.assertIn("world 2", log)
        self.assertEqual(log.count("step 1 "), 1)  # rank 0 alone logs
        ck = torch.load(os.path.join(out, "renderer.pt"), map_location="cpu")
        self.assertEqual(ck["recipe"]["world_size"], 2)


if __name__ == "__main__":
    unittest.main()
