"""`touch4d physics simulate` says what it prints and prints what it says; its frames pick a backend."""
import re

import pytest

from touch4d.cli import main

FALL = ("physics: {gravity: [0, -2, 0, 0], rate: 200}\n"
        "objects:\n  - name: floor\n    shape: tesseract\n    size: 0.2\n    position: [0, -3, 0, 1.5]\n"
        "    physics: {static: true}\n"
        "  - name: ball\n    shape: 24-cell\n    size: 0.2\n    position: [0, 0.5, 0, 1.5]\n"
        "    physics: {velocity: [0.5, 0, 0, 0], angular_velocity: [[xy, 45]]}\n")


def test_the_help_promises_in_the_text_only_what_the_text_prints(tmp_path, capsys):
    path = tmp_path / "fall.yaml"
    path.write_text(FALL)
    with pytest.raises(SystemExit):
        main(["physics", "simulate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    promised = help_text.split("print", 1)[1].split("--json", 1)[0]   # what the text output promises
    assert main(["physics", "simulate", str(path), "--duration", "0.1"]) == 0
    text = capsys.readouterr().out
    for word in ("energy", "angular momentum", "position", "velocity", "turning", "orientation"):
        if word in promised:
            assert re.search(word, text), f"the help promises {word!r} in the text output"
    assert "orientation" in help_text.split("--json", 1)[1]       # where the orientation is
    assert "ball:" in text and "floor:" not in text                # per moving object


def test_the_frames_are_drawn_by_the_backend_asked_and_both_draw_the_same_scene(tmp_path, capsys):
    import numpy as np
    from PIL import Image

    images = {}
    for backend in ("gpu", "clip"):
        out = tmp_path / f"{backend}.png"
        assert main(["physics", "simulate", "config/scenes/physics-drop.yaml", "--duration", "0.2", "--frames",
                     str(out), "--frame-count", "2", "--frame-size", "160x120", "--backend", backend]) == 0
        images[backend] = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert capsys.readouterr().err.count("wrote") == 2
    lit = {k: image.sum(axis=2) > 60 for k, image in images.items()}
    assert lit["gpu"].mean() > 0.05 and (lit["gpu"] == lit["clip"]).mean() > 0.97    # the same bodies, drawn
    with pytest.raises(SystemExit):
        main(["physics", "simulate", "config/scenes/physics-drop.yaml", "--frames", "x.png", "--backend", "vulkan"])
    assert "invalid choice: 'vulkan'" in capsys.readouterr().err
