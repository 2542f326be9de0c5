"""tools/gallery.py on a small setting: every picture written."""

from conftest import load_tool


def test_the_gallery_writes_its_pictures(tmp_path):
    tool = load_tool("gallery")
    assert tool.main(["--out", str(tmp_path), "--frames", "2", "--width", "48"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(shot[0] for shot in tool.SHOTS.values())
    import cv2

    image = cv2.imread(str(tmp_path / "organ_cut.png"))
    assert image.shape == (36, 48, 3) and image.min() < 200  # the organ is in the picture
