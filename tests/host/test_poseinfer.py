"""poseinfer as other tools call it: `poseinfer --model M IMAGE|DIR ...`,
one JSON object per image, exit 0 / 1 / 2 (docs/poseinfer.md)."""
import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pihelpers import ROOT, sphere_frame

cv2 = pytest.importorskip("cv2")

KEYS = {"file", "x", "y", "z", "ms", "circle"}  # circle: docs/poseinfer.md
# The sphere's circle and the confidence (docs/refine.md; note only when not confident).
EXTRA = {"circle", "confident", "residual", "note"}


def assert_pose(line, path):
    assert KEYS <= set(line) <= KEYS | EXTRA, line
    assert line["file"] == str(path)
    for k in ("x", "y", "z", "ms"):
        assert isinstance(line[k], (int, float)) and math.isfinite(line[k])
    assert line["ms"] > 0


def assert_error(line, path, *words):
    assert set(line) == {"file", "error"}, line
    assert line["file"] == str(path)
    for w in words:
        assert w in line["error"], line["error"]


@pytest.mark.valgrind
def test_good_frame(run, models, frames):
    r = run("--model", models["good"], frames["good.png"], valgrind=True)
    assert r.rc == 0, r.stderr
    assert len(r.lines) == 1
    assert_pose(r.lines[0], frames["good.png"])


def test_formats_gray_rgba_jpeg(run, models, frames):
    names = ["good.png", "good.jpg", "gray.png", "rgba.png"]
    r = run("--model", models["good"], *[frames[n] for n in names])
    assert r.rc == 0, r.stderr
    assert [l["file"] for l in r.lines] == [str(frames[n]) for n in names]
    for l, n in zip(r.lines, names):
        assert_pose(l, frames[n])


def test_same_frame_same_angles(run, models, frames):
    r = run("--model", models["good"], frames["good.png"], frames["good.png"])
    assert r.rc == 0
    a, b = r.lines
    assert (a["x"], a["y"], a["z"]) == (b["x"], b["y"], b["z"])


@pytest.mark.valgrind
def test_bad_images_then_good_one(run, models, frames):
    bad = ["truncated.png", "truncated.jpg", "corrupt.png", "empty.png", "text.png", "nosphere.png"]
    args = [frames[n] for n in bad] + [frames["good.png"]]
    r = run("--model", models["good"], *args, valgrind=True)
    assert r.rc == 1, r.stderr
    assert len(r.lines) == len(args)
    for line, n in zip(r.lines, bad):
        assert_error(line, frames[n])
    assert_error(r.lines[bad.index("nosphere.png")], frames["nosphere.png"], "no sphere found in frame")
    assert_error(r.lines[bad.index("truncated.jpg")], frames["truncated.jpg"], "truncated")
    assert_error(r.lines[bad.index("empty.png")], frames["empty.png"], "empty")
    assert_pose(r.lines[-1], frames["good.png"])


def test_missing_image(run, models, tmp_path):
    p = tmp_path / "nope.png"
    r = run("--model", models["good"], p)
    assert r.rc == 1
    assert_error(r.lines[0], p, "No such file")


@pytest.mark.valgrind
def test_huge_image_refused_before_decoding(run, models, frames):
    r = run("--model", models["good"], frames["huge_header.png"], valgrind=True)
    assert r.rc == 1
    assert_error(r.lines[0], frames["huge_header.png"], "60000x60000", "limit")


def test_max_pixels_flag(run, models, frames):
    r = run("--model", models["good"], "--max-pixels", "10000", frames["good.png"], frames["good.jpg"])
    assert r.rc == 1
    assert_error(r.lines[0], frames["good.png"], "limit")
    assert_error(r.lines[1], frames["good.jpg"], "limit")


def test_real_huge_image(run, models, tmp_path):
    # 9000 x 8000 = 72 Mpx, over the default limit of 64 Mpx (compresses small);
    # refused from its header, before any pixel is allocated.
    p = tmp_path / "big.png"
    img = np.zeros((8000, 9000), np.uint8)
    cv2.circle(img, (4500, 4000), 2000, 255, -1)
    cv2.imwrite(str(p), img)
    r = run("--model", models["good"], p)
    assert r.rc == 1
    assert_error(r.lines[0], p, "9000x8000", "limit")


def test_directory_sorted_and_filtered(run, models, tmp_path):
    d = tmp_path / "dir"
    d.mkdir()
    for name, seed in [("b.png", 1), ("a.png", 2), ("c.JPG", 3)]:
        cv2.imwrite(str(d / name), sphere_frame(seed=seed))
    (d / "notes.txt").write_text("not an image")
    (d / "sub").mkdir()
    r = run("--model", models["good"], d)
    assert r.rc == 0, r.lines
    assert [Path(l["file"]).name for l in r.lines] == ["a.png", "b.png", "c.JPG"]


def test_empty_directory(run, models, tmp_path):
    r = run("--model", models["good"], tmp_path)
    assert r.rc == 1
    assert "no image files" in r.lines[0]["error"]


def test_awkward_file_name_is_valid_json(run, models, frames, tmp_path):
    p = tmp_path / 'a "quoted" \\ näme\t.png'
    shutil.copy(frames["good.png"], p)
    r = run("--model", models["good"], p)
    assert r.rc == 0
    assert r.lines[0]["file"] == str(p)


@pytest.mark.valgrind
@pytest.mark.parametrize("variant,words", [
    ("nometa", ["nometa.onnx", "spherepose.preprocess"]),
    ("badmeta", ["badmeta.onnx", "spherepose.preprocess"]),
    ("wrongshape", ["wrongshape.onnx", "[-1,1,128,128]"]),
    ("wrongout", ["wrongout.onnx", "euler_deg"]),
    ("wrongname", ["wrongname.onnx", "\"input\""]),
])
def test_bad_models(run, models, frames, variant, words):
    r = run("--model", models[variant], frames["good.png"], valgrind=variant in ("nometa", "wrongshape"))
    assert r.rc == 2
    assert r.stdout == ""
    for w in words:
        assert w in r.stderr, r.stderr


def test_v1_model_lacking_a_preprocess_key_is_refused(run, frames, tmp_path):
    """The C side fills no preprocessing defaults: a sphere-crop-v1 model whose
    metadata lacks a key (training/preprocess.py DEFAULTS_V1, their one source)
    is refused, naming the key, as sphere-crop-v2 models are."""
    import make_model
    from training import preprocess

    def meta_pp(m):
        return next(p for p in m.metadata_props if p.key == "spherepose.preprocess")

    # the test models carry every key, as this project's exports always have
    good = json.loads(meta_pp(make_model.build("good")).value)
    assert set(good) == set(preprocess.DEFAULTS_V1), good
    for key in preprocess.DEFAULTS_V1:
        m = make_model.build("good")
        pp = json.loads(meta_pp(m).value)
        del pp[key]
        meta_pp(m).value = json.dumps(pp, sort_keys=True)
        path = tmp_path / f"no_{key}.onnx"
        path.write_bytes(m.SerializeToString())
        r = run("--model", path, frames["good.png"])
        assert r.rc == 2 and r.stdout == "", (key, r.rc, r.stdout)
        assert str(path) in r.stderr and f'"{key}"' in r.stderr, (key, r.stderr)


@pytest.mark.valgrind
def test_missing_model(run, frames, tmp_path):
    m = tmp_path / "missing.onnx"
    r = run("--model", m, frames["good.png"], valgrind=True)
    assert r.rc == 2
    assert str(m) in r.stderr and "No such file" in r.stderr


def test_not_an_onnx_model(run, frames, tmp_path):
    m = tmp_path / "junk.onnx"
    m.write_bytes(b"\x00garbage" * 100)
    r = run("--model", m, frames["good.png"])
    assert r.rc == 2
    assert str(m) in r.stderr


def test_rotmat_model(run, models, frames):
    r = run("--model", models["rotmat"], frames["good.png"])
    assert r.rc == 0
    rm = np.array(r.lines[0]["rotmat"])
    assert rm.shape == (3, 3)


def test_size64_model(run, models, frames):
    r = run("--model", models["size64"], "--timings", frames["good.png"])
    assert r.rc == 0
    line = r.lines[0]
    for k in ("decode_ms", "preprocess_ms", "locate_ms", "infer_ms", "cx", "cy", "r"):
        assert k in line
    assert 0 <= line["locate_ms"] <= line["preprocess_ms"]
    assert abs(line["cx"] - 320) < 2 and abs(line["cy"] - 256) < 2 and abs(line["r"] - 133) < 3


@pytest.mark.parametrize("args,words", [
    ([], ["no model"]),
    (["--model", "m.onnx"], ["no images"]),
    (["--bogus"], ["unrecognized option"]),
    (["--model", "m.onnx", "--threads", "zero", "x.png"], ["threads"]),
    (["--model", "m.onnx", "--continuous"], ["--camera"]),
])
def test_usage_errors(run, args, words):
    r = run(*args)
    assert r.rc == 2
    for w in words:
        assert w in r.stderr, r.stderr


def test_help(run):
    r = run("--help")
    assert r.rc == 0
    assert "usage: poseinfer" in r.stdout and "--serve" in r.stdout


def test_help_defaults_match_the_documented_table(run):
    """Each default --help states is the one docs/poseinfer.md's key table gives
    (tests/host/unit/test_config_doc.c holds that table to config.c)."""
    import re
    table = {}
    for line in (ROOT / "docs" / "poseinfer.md").read_text().splitlines():
        m = re.match(r"\| `(\w+)` \| (`([^`]*)`|none) \|", line)
        if m:
            table[m.group(1)] = m.group(3) if m.group(3) is not None else "none"
    text = " ".join(run("--help").stdout.split())  # the help wraps lines
    said = {key: value.split(":")[0] for value, key in re.findall(r"\(default ([^)]+)\) \[(\w+)\]", text)}
    said.update({key: value for key, value in re.findall(r"\b(\w+) \((0\d+)\)", text)})
    assert len(said) >= 10, said
    for key, value in said.items():
        assert key in table, f"--help gives a default for {key}, docs/poseinfer.md's table has no such key"
        assert table[key] == value, f"{key}: --help says {value}, docs/poseinfer.md says {table[key]}"


def test_config_file(run, models, frames, tmp_path):
    cfg = tmp_path / "poseinfer.conf"
    cfg.write_text(f"# test\nmodel = {models['good']}\ntimings = yes\n\nthreads=1\n")
    r = run("--config", cfg, frames["good.png"])
    assert r.rc == 0, r.stderr
    assert "infer_ms" in r.lines[0]
    # a flag overrides the file, wherever it stands
    r = run(frames["good.png"], "--model", models["nometa"], "--config", cfg)
    assert r.rc == 2 and "nometa.onnx" in r.stderr
    cfg.write_text("model = x.onnx\nspeed = 11\n")
    r = run("--config", cfg, frames["good.png"])
    assert r.rc == 2 and ":2)" in r.stderr and "speed" in r.stderr


def test_rendered_frames(run, models, tmp_path):
    """Frames from the renderer (sim render) with known poses. With the test
    model the angles mean nothing; the frames must still give a pose. With the
    trained model (training/models/Texture_3_color.onnx) and its texture, the
    angles must be near the truth."""
    sim = ROOT / ".venv" / "bin" / "sim"
    if not sim.exists():
        pytest.skip("sim render not installed")
    real_model = ROOT / "training" / "models" / "Texture_3_color.onnx"
    texture = None
    for cand in [ROOT / "build" / "textures" / "Texture_3_color.png"]:
        if cand.exists():
            texture = cand
    poses = [(0, 0, 0), (12, -7.5, 20), (-25, 15, -10)]
    if texture is None:
        texture = tmp_path / "tex.png"
        rng = np.random.default_rng(3)
        t = np.full((256, 512, 3), 230, np.uint8)
        for _ in range(60):
            cv2.circle(t, (int(rng.integers(0, 512)), int(rng.integers(0, 256))), int(rng.integers(5, 30)),
                       tuple(int(v) for v in rng.integers(0, 255, 3)), -1)
        cv2.imwrite(str(texture), t)
    paths = []
    for x, y, z in poses:
        p = tmp_path / f"{x}_{y}_{z}.png"
        proc = subprocess.run([str(sim), "render", "--texture", str(texture), "--pose", str(x), str(y), str(z),
                               "--out", str(p)], capture_output=True, text=True, timeout=120)
        if proc.returncode != 0:
            pytest.skip(f"sim render failed: {proc.stderr[-300:]}")
        paths.append(p)
    r = run("--model", models["good"], *paths)
    assert r.rc == 0, r.lines
    for l, p in zip(r.lines, paths):
        assert_pose(l, p)
    if real_model.exists() and texture.name == "Texture_3_color.png":
        r = run("--model", real_model, *paths)
        assert r.rc == 0, r.lines
        for l, pose in zip(r.lines, poses):
            for k, true in zip("xyz", pose):
                d = (l[k] - true + 180) % 360 - 180
                assert abs(d) < 5, (l, pose)


def test_install_runs_from_its_prefix(models, frames, tmp_path):
    """`make install DESTDIR=...`: the installed binary finds the ONNX Runtime
    copy through its rpath ($ORIGIN/../lib/poseinfer)."""
    if os.environ.get("POSEINFER") and Path(os.environ["POSEINFER"]).parent.name != "build":
        pytest.skip("install is tested with the plain build")
    dest = tmp_path / "dest"
    proc = subprocess.run(["make", "-s", "-C", str(ROOT / "host"), "install", f"DESTDIR={dest}", "PREFIX=/usr"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    exe = dest / "usr" / "bin" / "poseinfer"
    unit = (dest / "usr" / "lib" / "systemd" / "system" / "poseinfer.service").read_text()
    assert "ExecStart=/usr/bin/poseinfer --config /etc/poseinfer.conf" in unit
    assert (dest / "usr" / "include" / "poseinfer.h").exists()
    out = subprocess.run([str(exe), "--model", str(models["good"]), str(frames["good.png"])],
                         capture_output=True, text=True, timeout=60,
                         env={"PATH": "/usr/bin:/bin", "LD_LIBRARY_PATH": ""})
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["file"] == str(frames["good.png"])
    ldd = subprocess.run(["ldd", str(exe)], capture_output=True, text=True).stdout
    assert str(dest / "usr" / "bin" / ".." / "lib" / "poseinfer") in ldd, ldd


def test_installed_unit_passes_systemd_verify(tmp_path):
    """The installed unit as systemd itself reads it (`systemd-analyze verify`:
    its keys, values and ExecStart binary), installed into a real prefix so
    that the paths it names exist."""
    if os.environ.get("POSEINFER") and Path(os.environ["POSEINFER"]).parent.name != "build":
        pytest.skip("install is tested with the plain build")
    sa = shutil.which("systemd-analyze")
    if not sa:
        pytest.skip("systemd-analyze is not installed")
    prefix = tmp_path / "usr"
    proc = subprocess.run(["make", "-s", "-C", str(ROOT / "host"), "install", f"PREFIX={prefix}"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    unit = prefix / "lib" / "systemd" / "system" / "poseinfer.service"
    assert f"ExecStart={prefix}/bin/poseinfer --config /etc/poseinfer.conf" in unit.read_text()
    v = subprocess.run([sa, "verify", str(unit)], capture_output=True, text=True, timeout=120)
    assert v.returncode == 0 and v.stderr.strip() == "", v.stderr


def test_fifo_and_devices_are_refused_not_waited_on(run, models, frames, tmp_path):
    """A FIFO (no writer) among the images, given directly or inside a directory
    argument, and a character device: each gets an error line naming it, at
    once; the good frames around them still give poses."""
    fifo = tmp_path / "f.png"
    os.mkfifo(fifo)
    d = tmp_path / "dir"
    d.mkdir()
    shutil.copy(frames["good.png"], d / "a.png")
    os.mkfifo(d / "b.png")
    r = run("--model", models["good"], frames["good.png"], fifo, "/dev/null", d, timeout=20)
    assert r.rc == 1, r.stderr
    assert len(r.lines) == 5, r.stdout
    assert r.lines[0]["file"] == str(frames["good.png"]) and "error" not in r.lines[0]
    assert_error(r.lines[1], fifo, "not a regular file", "FIFO")
    assert_error(r.lines[2], "/dev/null", "not a regular file", "character device")
    assert r.lines[3]["file"] == str(d / "a.png") and "error" not in r.lines[3]
    assert_error(r.lines[4], d / "b.png", "not a regular file", "FIFO")


def test_config_fifo_is_refused(run, tmp_path):
    fifo = tmp_path / "poseinfer.conf"
    os.mkfifo(fifo)
    r = run("--config", fifo, "x.png", timeout=20)
    assert r.rc == 2 and str(fifo) in r.stderr and "not a regular file" in r.stderr


def test_file_name_that_is_not_utf8_gives_valid_json(poseinfer, models, frames, tmp_path):
    """Bytes of a file name that are not UTF-8 are written as \\ufffd: every
    stdout line is valid UTF-8 JSON (docs/poseinfer.md)."""
    d = os.fsencode(tmp_path)
    good = d + b"/caf\xe9 \xff.png"
    shutil.copy(frames["good.png"], good)
    missing = d + b"/\xc3(\x80.png"
    proc = subprocess.run([os.fsencode(poseinfer), b"--model", os.fsencode(models["good"]), good, missing],
                          capture_output=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    lines = [json.loads(l.decode("utf-8")) for l in proc.stdout.splitlines()]
    assert lines[0]["file"] == str(tmp_path) + "/caf\ufffd \ufffd.png" and "x" in lines[0]
    assert lines[1]["file"] == str(tmp_path) + "/\ufffd(\ufffd.png" and "No such file" in lines[1]["error"]


def test_unit_hardening_rating(tmp_path):
    """`systemd-analyze security` rates the unit's hardening (offline, from the
    file): it stays in the OK band (below 4; measured 1.7, docs/poseinfer.md)."""
    sa = shutil.which("systemd-analyze")
    if not sa:
        pytest.skip("systemd-analyze is not installed")
    unit = tmp_path / "poseinfer.service"
    unit.write_text((ROOT / "host" / "poseinfer.service").read_text().replace("@PREFIX@", "/usr/local"))
    v = subprocess.run([sa, "security", "--offline=yes", "--no-pager", str(unit)], capture_output=True, text=True,
                       timeout=120)
    if "--offline" in v.stderr:
        pytest.skip("this systemd-analyze has no --offline")
    import re
    m = re.search(r"Overall exposure level for poseinfer.service: ([0-9.]+)", v.stdout)
    assert m, v.stdout + v.stderr
    assert float(m.group(1)) < 4.0, v.stdout
