"""``sc3d-train predict`` on images from the wild (the images attack): defects found by feeding it
the files a researcher has at hand; expected values are derived by hand, never from the code
under test."""
from __future__ import annotations

import numpy as np
from PIL import Image



def test_an_rgb_png_with_a_transparent_colour_is_composited_like_a_cut_out(tmp_path):
    """A cut-out PNG whose transparent pixels share one colour is stored by PNG optimisers
    (optipng, oxipng, PIL's ``transparency=``) as RGB plus a tRNS colour key, not as RGBA; viewers
    show those pixels transparent. ``predict`` took RGB "as is", so the model saw the key colour
    (black here) as the background instead of the training background. By hand: a grey square
    (128) on black, black marked transparent, on the background (10, 200, 30) must read as the
    square on that background; the same pixels without the key (the control) stay black."""
    from sc3d_train.evaluation.predict import load_image

    pixels = np.zeros((64, 64, 3), dtype=np.uint8)
    pixels[16:48, 16:48] = 128
    Image.fromarray(pixels).save(tmp_path / "keyed.png", transparency=(0, 0, 0))
    Image.fromarray(pixels).save(tmp_path / "opaque.png")
    assert Image.open(tmp_path / "keyed.png").mode == "RGB"  # the file is RGB + tRNS, not RGBA
    background = [10, 200, 30]
    expected = np.empty((64, 64, 3), dtype=np.float32)
    expected[:] = np.array(background, dtype=np.float32) / 255.0
    expected[16:48, 16:48] = 128 / 255.0
    np.testing.assert_allclose(load_image(tmp_path / "keyed.png", 64, background), expected, atol=1e-6)
    np.testing.assert_allclose(load_image(tmp_path / "opaque.png", 64, background), pixels / 255.0, atol=1e-6)

