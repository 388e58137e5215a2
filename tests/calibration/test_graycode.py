"""Gray code: OpenCV's pattern order, exact round trip under gamma / ambient / noise, real captures."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.graycode import check_decodes, decode_graycode, graycode_bits, graycode_pattern_count, graycode_patterns


def test_pattern_order_is_opencvs():
    ours = graycode_patterns(1024, 768)
    ok, ref = cv2.structured_light.GrayCodePattern.create(1024, 768).generate()
    assert len(ours) == graycode_pattern_count(1024, 768) == 42 == len(ref) + 2
    assert all(np.array_equal(a, b) for a, b in zip(ours, ref))
    assert (ours[-2] == 255).all() and (ours[-1] == 0).all()


@pytest.mark.parametrize("width, height", [(1024, 768), (100, 60), (37, 5)])
def test_round_trip_exact(width, height):
    dec = decode_graycode(graycode_patterns(width, height), projector_width=width, projector_height=height)
    v, u = np.mgrid[0:height, 0:width]
    assert dec.valid.all()
    assert np.array_equal(dec.u_proj, u) and np.array_equal(dec.v_proj, v)


def test_round_trip_with_gamma_ambient_global_and_noise():
    # Each camera pixel sees one projector pixel through gamma 2.2, with ambient light, a constant global
    # term and sensor noise, stored as 16-bit: decoding must still be exact everywhere.
    w, h = 300, 200
    rng = np.random.default_rng(1)
    pats = graycode_patterns(w, h)
    imgs = []
    for p in pats:
        radiance = 0.6 * (p / 255.0) ** 2.2 + 0.08 + 0.05
        imgs.append(np.clip((radiance + rng.normal(0, 2 / 255, p.shape)) * 65535, 0, 65535).astype(np.uint16))
    dec = decode_graycode(imgs, projector_width=w, projector_height=h)
    v, u = np.mgrid[0:h, 0:w]
    assert dec.valid.mean() > 0.995
    assert np.array_equal(dec.u_proj[dec.valid], u[dec.valid]) and np.array_equal(dec.v_proj[dec.valid], v[dec.valid])
    assert np.median(dec.direct) == pytest.approx(0.6 * 255, rel=0.05)


def test_unlit_pixels_are_invalid():
    w, h = 64, 32
    pats = [p.astype(np.float32) * 0.8 + 20 for p in graycode_patterns(w, h)]
    for p in pats:
        p[:, :20] = 20  # a shadow: only ambient light
    dec = decode_graycode([p.astype(np.uint8) for p in pats], projector_width=w, projector_height=h)
    assert not dec.valid[:, :20].any() and dec.valid[:, 22:].all()


def test_wrong_number_of_images_says_how_many():
    with pytest.raises(CalibrationError, match="has 42 images.*got 40"):
        decode_graycode(graycode_patterns(1024, 768)[:40], projector_width=1024, projector_height=768)


def test_a_code_that_does_not_decode_is_reported():
    flat = [np.full((50, 60), 128, np.uint8)] * graycode_pattern_count(64, 32)
    dec = decode_graycode(flat, projector_width=64, projector_height=32)
    with pytest.raises(CalibrationError, match="does not decode.*settle"):
        check_decodes(dec, name="pose1")


def test_bits():
    assert graycode_bits(1024) == 10 and graycode_bits(768) == 10 and graycode_bits(1025) == 11


@pytest.mark.shared_data
def test_real_capture_matches_opencv_decoder(shared_data):
    d = shared_data / "procam_calibration_kamino410"
    imgs = [cv2.imread(str(d / "capture_0" / f"graycode_{i:02d}.png"), cv2.IMREAD_GRAYSCALE) for i in range(42)]
    patterns = [cv2.imread(str(d / "graycode_pattern" / f"pattern_{i:02d}.png"), cv2.IMREAD_GRAYSCALE) for i in range(42)]
    assert all(np.array_equal(a, b) for a, b in zip(graycode_patterns(1024, 768), patterns))
    dec = decode_graycode(imgs, projector_width=1024, projector_height=768)
    # REFERENCE.md: decoded columns span ~62..827, rows reach 767; about two thirds of the image is lit.
    assert 0.5 < dec.valid_fraction < 0.8
    assert abs(int(dec.u_proj[dec.valid].min()) - 62) <= 5 and abs(int(dec.u_proj[dec.valid].max()) - 827) <= 5
    assert dec.v_proj[dec.valid].max() == 767
    # OpenCV's own decoder (thresholds of the data's README: black 40, white 5) on a sample of pixels.
    g = cv2.structured_light.GrayCodePattern.create(1024, 768)
    g.setBlackThreshold(40)
    g.setWhiteThreshold(5)
    rng = np.random.default_rng(0)
    vv, uu = np.nonzero(dec.valid & (dec.direct > 60))
    pick = rng.choice(len(uu), 300, replace=False)
    decoded = agree = 0
    for i in pick:
        err, pix = g.getProjPixel(imgs[:40], int(uu[i]), int(vv[i]))
        if err:  # OpenCV's fixed white threshold rejects some pixels we keep
            continue
        decoded += 1
        agree += abs(pix[0] - dec.u_proj[vv[i], uu[i]]) <= 1 and abs(pix[1] - dec.v_proj[vv[i], uu[i]]) <= 1
    assert decoded >= 0.8 * len(pick)
    assert agree >= 0.99 * decoded
