"""`touch4d render --slice-w`: a cut the view does not show, or one outside every object's range of
w (an empty frame), is said in one line naming the flag and the objects' range."""
import pytest

from touch4d.cli import main

SCENE = "config/scenes/hypercube.yaml"     # a tesseract of size 1.2 at w = 1.5: w 0.9..2.1, projection view


def render(tmp_path, *extra):
    return main(["render", "--scene", SCENE, "--size", "32x32", "--samples", "0", *extra, "-o", str(tmp_path / "f.png")])


@pytest.mark.timeout(120)
def test_slice_w_without_a_slice_view_is_said_to_be_ignored(tmp_path, capsys):
    assert render(tmp_path, "--slice-w", "1.2") == 0
    err = capsys.readouterr().err
    assert "warning: --slice-w 1.2 is ignored: the view is the projection" in err, err


@pytest.mark.timeout(120)
def test_a_cut_outside_every_object_names_the_flag_and_their_range(tmp_path, capsys):
    assert render(tmp_path, "--view", "slice", "--slice-w", "5") == 0
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and "--slice-w 5 cuts no object" in err and "hypercube 0.9..2.1" in err, err
    assert render(tmp_path, "--view", "both", "--slice-w", "1.2") == 0       # through the tesseract: nothing to say
    assert "warning" not in capsys.readouterr().err


def test_serve_help_says_the_participants_per_core_default(capsys):
    """`study serve --help` gives --max-participants' default as the server's own constant, not a copy."""
    from touch4d.web.studyserver import PARTICIPANTS_PER_CORE

    with pytest.raises(SystemExit):
        main(["study", "serve", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"Default: {PARTICIPANTS_PER_CORE} per CPU core" in help_text, help_text
    assert "--per-process" not in help_text and "ROLE.PARAM" not in help_text
