"""tools/gallery.py on a small setting: every picture written."""

from conftest import load_tool


def test_the_gallery_writes_its_pictures(tmp_path):
    tool = load_tool("gallery")
    assert tool.main(["--out", str(tmp_path), "--frames", "2", "--width", "48"]) == 0
    names = [shot[0] for shot in tool.SHOTS.values()] + [tool.AR_PNG, tool.NODES_PNG]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)
    import cv2

    image = cv2.imread(str(tmp_path / "organ_cut.png"))
    assert image.shape == (36, 48, 3) and image.min() < 200  # the organ is in the picture
    overlay = cv2.imread(str(tmp_path / tool.AR_PNG))
    assert overlay.shape[1] == 48 and overlay.std() > 1.0  # a video frame, not a blank
    plot = cv2.imread(str(tmp_path / tool.NODES_PNG))
    assert plot is not None and plot.shape[1] > plot.shape[0]  # the two panels side by side
