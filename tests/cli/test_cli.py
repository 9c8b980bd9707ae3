"""End-to-end tests of the `smf` command through its entry point (and one real subprocess)."""

import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest

from stablemofusion.serve.site import WEBGPU_FILES
from stablemofusion.cli.main import main
from stablemofusion.motion.features import canonicalize, features_from_joints


def run(*argv):
    return main([str(a) for a in argv])


@pytest.fixture
def ref_joints_file(hml_ref):
    return hml_ref / "new_joints" / "000000.npy"


def test_render_video_and_still_of_reference_motion(ref_joints_file, hml_ref, tmp_path):
    assert run("render", ref_joints_file, "--out", tmp_path / "m.mp4", "--title", "kick") == 0
    frames = iio.imread(tmp_path / "m.mp4", index=None)
    assert frames.shape[0] == 116
    # features input is detected by shape
    assert run("render", hml_ref / "new_joint_vecs" / "000000.npy", "--frame", 20, "--out", tmp_path / "s.png") == 0
    img = iio.imread(tmp_path / "s.png")
    assert img.shape[0] == 480 and (img[..., :3] < 200).any(axis=-1).mean() > 0.01


def test_convert_joints_features_joints(ref_joints_file, tmp_path):
    assert run("convert", ref_joints_file, tmp_path / "f.npy") == 0
    feats = np.load(tmp_path / "f.npy")
    assert feats.shape == (115, 263)
    assert run("convert", tmp_path / "f.npy", tmp_path / "j.npy") == 0
    joints = np.load(tmp_path / "j.npy")
    ref = canonicalize(np.load(ref_joints_file))[:-1]
    assert joints.shape == (115, 22, 3) and np.abs(joints - ref).max() < 1e-4


def test_bvh_export_then_import_within_a_centimetre(ref_motion, tmp_path):
    _, joints, feats = ref_motion
    np.save(tmp_path / "f.npy", feats)
    assert run("convert", tmp_path / "f.npy", tmp_path / "m.bvh") == 0
    text = (tmp_path / "m.bvh").read_text()
    assert text.startswith("HIERARCHY") and "ROOT pelvis" in text and "Frame Time: 0.05" in text
    assert run("convert", tmp_path / "m.bvh", tmp_path / "back.npy", "--to", "joints") == 0
    back = np.load(tmp_path / "back.npy")
    assert back.shape == joints.shape
    assert np.linalg.norm(back - joints, axis=-1).max() < 0.01


def test_bvh_round_trip_of_features(ref_motion, tmp_path):
    _, joints, _ = ref_motion
    np.save(tmp_path / "j.npy", joints)
    assert run("convert", tmp_path / "j.npy", tmp_path / "m.bvh") == 0
    assert run("convert", tmp_path / "m.bvh", tmp_path / "f.npy", "--to", "features") == 0
    assert np.abs(np.load(tmp_path / "f.npy") - features_from_joints(joints)).max() < 0.05


@pytest.mark.parametrize("setup, argv, message", [
    (None, ["render", "{d}/missing.npy", "--out", "{d}/x.mp4"], "no such file"),
    ("bad_shape", ["render", "{d}/in.npy", "--out", "{d}/x.mp4"], "neither joints"),
    ("nan", ["convert", "{d}/in.npy", "{d}/x.bvh"], "NaN"),
    ("good", ["convert", "{d}/in.npy", "{d}/x.txt"], "unsupported output extension"),
    ("good_txt", ["convert", "{d}/in.txt", "{d}/x.npy"], "unsupported motion file extension"),
    ("good", ["render", "{d}/in.npy", "--out", "{d}/x.avi"], "unsupported output format"),
    ("good", ["render", "{d}/in.npy", "--frame", "500", "--out", "{d}/x.png"], "out of range"),
    ("garbage", ["render", "{d}/in.npy", "--out", "{d}/x.mp4"], "not a readable .npy"),
    ("good", ["site", "--out", "{d}"], "not a site"),  # a folder of other files is never replaced
    (None, ["site", "--out", "{d}/x.site", "--checkpoint", "{d}/nothing"], "holds no portable graphs"),
    (None, ["site", "--out", "{d}/x.site", "--webgpu", "{d}/nothing"], "no such folder"),
    ("webgpu_part", ["site", "--out", "{d}/x.site", "--webgpu", "{d}"], "not there; give the dist/ folder"),
    ("webgpu_old", ["site", "--out", "{d}/x.site", "--webgpu", "{d}"], "ONNX Runtime Web 1.17.0, the page runs"),
    (None, ["generate", "--timeline", "walk:1e308", "--out", "{d}/x.out"], "at most 120 s"),
    ("deep_path", ["generate", "a person walks", "--path", "{d}/in.json", "--out", "{d}/x.out"], "nested too deeply"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, setup, argv, message):
    good = np.zeros((10, 22, 3)) + np.linspace(0, 1, 22)[None, :, None]
    if setup == "bad_shape":
        np.save(tmp_path / "in.npy", np.zeros((10, 5)))
    elif setup == "nan":
        np.save(tmp_path / "in.npy", np.full((10, 22, 3), np.nan))
    elif setup == "good":
        np.save(tmp_path / "in.npy", good)
    elif setup == "good_txt":
        (tmp_path / "in.txt").write_text("x")
    elif setup == "garbage":
        (tmp_path / "in.npy").write_bytes(b"not numpy")
    elif setup in ("webgpu_part", "webgpu_old"):  # a WebGPU build with files missing, or of another version
        for name in WEBGPU_FILES[:1] if setup == "webgpu_part" else WEBGPU_FILES:
            (tmp_path / name).write_text("/*!\n * ONNX Runtime Web v1.17.0\n */\n")
    elif setup == "deep_path":
        (tmp_path / "in.json").write_text("[" * 2000 + "]" * 2000)
    code = run(*[a.format(d=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not any(p.name.startswith("x.") for p in tmp_path.iterdir())


def test_console_script_exit_code(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", "convert", str(tmp_path / "nope.npy"),
                           str(tmp_path / "o.npy")], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.startswith("smf: error: no such file")
    proc = subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", "render"], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1


def test_packaged_example_works_without_shared_data(tmp_path):
    assert run("convert", "example:wave-both-hands", tmp_path / "w.bvh") == 0
    assert run("convert", "example:wave-both-hands", tmp_path / "f.npy") == 0
    assert np.load(tmp_path / "f.npy").shape == (117, 263)
    assert run("render", "example:wave-both-hands", "--frame", 60, "--out", tmp_path / "w.png") == 0
    assert (tmp_path / "w.png").stat().st_size > 10_000


def test_settings_flags_with_a_none_default_take_numbers(tmp_path, capsys):
    """--max-frames of train-evaluator defaults to None (the corpus skeleton's) and still takes an integer."""
    assert main(["train-evaluator", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "ev"),
                 "--max-frames", "120"]) == 2
    err = capsys.readouterr().err
    assert "invalid" not in err and "does not exist" in err


@pytest.mark.parametrize("argv", [["--help"], ["generate"], ["generate", "--help"], ["edit", "x"], ["convert"],
                                  ["render", "--help"], ["serve", "--help"], ["addon", "--help"], ["info", "--help"],
                                  ["generate", "walk", "--out", "o", "--guidance", "-3"]])
def test_help_and_argument_errors_import_no_model_code(argv):
    """`smf --help`, a command's --help and argument errors answer at once: no torch, numpy or model import."""
    code = ("import sys\nfrom stablemofusion.cli.main import main\ntry:\n    rc = main(sys.argv[1:])\n"
            "except SystemExit as e:\n    rc = e.code\nheavy = [m for m in ('torch', 'numpy', 'transformers') "
            "if m in sys.modules]\nprint('HEAVY', heavy, 'RC', rc)")
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=60)
    assert "HEAVY [] RC" in out.stdout, (out.stdout, out.stderr)
    if argv[-1] != "--help":
        assert out.stdout.strip().endswith("RC 2") and out.stderr.count("\n") == 1 and "error:" in out.stderr


def test_help_shows_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["generate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: 32)" in text and "(default: npy,bvh,glb)" in text and "post by default" in text


def test_convert_and_render_never_replace_an_output_silently(ref_joints_file, tmp_path, capsys):
    out = tmp_path / "f.npy"
    out.write_bytes(b"mine")
    assert run("convert", ref_joints_file, out) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == b"mine"
    assert run("convert", ref_joints_file, out, "--overwrite") == 0 and np.load(out).shape == (115, 263)
    png = tmp_path / "s.png"
    png.write_bytes(b"mine")
    assert run("render", ref_joints_file, "--frame", 3, "--out", png) == 2 and png.read_bytes() == b"mine"


def test_serve_on_a_busy_port_is_one_line(tmp_path):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", "serve", "--port", str(port)],
                             capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert out.stderr.count("\n") == 1 and out.stderr.startswith("smf: error: cannot listen on 127.0.0.1:")
    assert "in use" in out.stderr and out.stdout == ""


@pytest.mark.parametrize("array, words", [(np.zeros((40, 22, 3)), "has no length"),
                                          (np.ones((40, 22, 3), dtype=complex), "not real numbers")])
def test_convert_of_joints_no_body_has_is_one_line(array, words, tmp_path, capsys):
    np.save(tmp_path / "m.npy", array)
    assert run("convert", tmp_path / "m.npy", tmp_path / "m.bvh") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and not (tmp_path / "m.bvh").exists()


def test_export_without_a_checkpoint_names_it_in_one_line(tmp_path, capsys):
    """`smf export` needs --checkpoint unless it writes the final stage's graphs."""
    assert main(["export", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "--checkpoint is required (but with --final-stage)" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()
