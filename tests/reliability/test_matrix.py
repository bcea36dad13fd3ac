"""The bad-input matrix: every verb that reads or writes, against the faults users hand it.

Each row of :data:`ROWS` runs one ``fastdet`` command line and holds it to
the promises of ``docs/reliability.md``:

* the exit status is the documented one: 0 when fastdet copes (converts the
  input, finds nothing), 2 when it refuses;
* refused: stderr is exactly one line, ``fastdet: error: ...``, naming the
  file at fault and matching the row's problem;
* coped: stderr is empty (but for the notice that kernels are compiling);
* never a traceback;
* nothing half-written: every file the row guards is byte-for-byte what it
  was before (or still absent);
* no temporary file is left in any folder the command touched.

Rows are data: those of ``run`` and its stream inputs are in
``matrix_video_rows.py``; the machinery (:class:`~matrix.Row`, the checks) is in
``matrix_checks.py``.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import stat
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from matrix_checks import (TABLE_HEADER, InputFolder, Row, check_row, fifo_reader, full_disk,
                           markdown_table, read_only_out, s)
from matrix_batch_rows import BATCH_ROWS
from matrix_video_rows import VIDEO_ROWS, VideoInputs

from fastdet.cli.app import main
from fastdet.detector.model import load_model
from filesystems import private_device
from image_files import png_claiming

ROOT = Path(__file__).resolve().parents[2]


# -- the inputs every row draws from ---------------------------------------------
class Inputs(InputFolder):
    """Good and bad files of every kind, made once (see :func:`inputs`)."""

    def __init__(self, folder, data_dir):
        self.dir = folder
        source = data_dir / "test_images" / "test1.jpg"
        jpeg = source.read_bytes()
        image = cv2.imread(str(source))
        rng = np.random.default_rng(17)
        # Images.
        self.image = self.file("image.jpg", jpeg)
        self.file("empty.jpg", b"")
        self.file("random.jpg", rng.bytes(4096))
        self.file("truncated.jpg", jpeg[:len(jpeg) // 2])
        (folder / "folder.jpg").mkdir()
        cv2.imwrite(str(folder / "grey.png"), cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        cv2.imwrite(str(folder / "rgba.png"), cv2.cvtColor(image, cv2.COLOR_BGR2BGRA))
        cv2.imwrite(str(folder / "deep.png"), image.astype(np.uint16) * 257)
        cv2.imwrite(str(folder / "tiny.png"), image[:10, :10])
        cv2.imwrite(str(folder / "huge.jpg"), cv2.resize(image, (7680, 4320)))
        self.file("claims_huge.png", png_claiming(40000, 40000))
        # Models.
        bundled = (ROOT / "fastdet" / "data" / "default_model.npz").read_bytes()
        self.file("empty.npz", b"")
        self.file("random.npz", rng.bytes(4096))
        self.file("truncated.npz", bundled[:len(bundled) // 2])
        (folder / "folder.npz").mkdir()
        self.file("tampered.npz", self.tampered(bundled))
        self.file("mismatched.npz", self.rewritten(bundled, weights=np.zeros(10, np.float32)))
        self.file("future.npz", self.rewritten(bundled, format_version=2))
        # Configs.
        self.file("empty.toml", b"")
        self.file("random.toml", rng.bytes(512))
        self.file("truncated.toml", b"[search]\ndecision_thr")
        (folder / "folder.toml").mkdir()
        self.file("unknown.toml", b"[search]\nthreshold = 1\n")
        self.file("wrong_type.toml", b"[heat]\nthreshold = \"high\"\n")
        # Annotations (image.jpg is test1.jpg).
        truth = json.loads((data_dir / "test_images" / "annotations.json").read_text())
        objects = truth["images"]["test1.jpg"]
        self.annotations = self.file("annotations.json",
                                     json.dumps({"images": {"image.jpg": objects}}).encode())
        self.file("damaged_image.json", json.dumps({"images": {"truncated.jpg": []}}).encode())
        self.file("empty.json", b"")
        self.file("random.json", rng.bytes(512))
        self.file("truncated.json", self.annotations.read_bytes()[:40])
        (folder / "folder.json").mkdir()
        self.file("wrong.json", b'{"images": [1, 2]}')
        # Training data: 30 + 30 synthetic crops; the same with a damaged one;
        # class folders without images.
        self.data = folder / "data"
        for label, group in ((1, "vehicles/GTI_Far"), (0, "non-vehicles/GTI")):
            crops = self.data / group
            crops.mkdir(parents=True)
            for i in range(30):
                crop = rng.integers(0, 60, (64, 64, 3), dtype=np.uint8)
                if label:
                    crop[20:48, 8:56] = 220
                cv2.imwrite(str(crops / f"image{i:04d}.png"), crop)
        self.damaged_data = folder / "damaged_data"
        shutil.copytree(self.data, self.damaged_data)
        (self.damaged_data / "vehicles" / "GTI_Far" / "image0007.png").write_bytes(rng.bytes(300))
        for group in ("vehicles", "non-vehicles"):
            (folder / "empty_data" / group).mkdir(parents=True)
        # Private stand-ins for /dev/full and /dev/null: a bug that renames
        # over its output must not replace the machine's own devices.
        (folder / "dev").mkdir()
        self.full = private_device(folder / "dev", "full")
        self.null = private_device(folder / "dev", "null")

    def device(self, name):
        path = getattr(self, name)
        if path is None:
            pytest.skip("needs root to make a device node")
        return path

    @staticmethod
    def tampered(bundled):
        with np.load(io.BytesIO(bundled)) as archive:
            weights, metadata = archive["weights"].copy(), archive["metadata"]
        weights[100] += 0.5
        buffer = io.BytesIO()
        np.savez(buffer, weights=weights, metadata=metadata)
        return buffer.getvalue()

    @staticmethod
    def rewritten(bundled, weights=None, **changes):
        with np.load(io.BytesIO(bundled)) as archive:
            metadata = json.loads(archive["metadata"].tobytes())
            weights = archive["weights"] if weights is None else weights
        metadata.update(changes)
        import hashlib
        metadata["weights_sha256"] = hashlib.sha256(weights.astype("<f4").tobytes()).hexdigest()
        metadata["feature_length"] = int(weights.size)
        buffer = io.BytesIO()
        np.savez(buffer, weights=weights,
                 metadata=np.frombuffer(json.dumps(metadata).encode(), np.uint8))
        return buffer.getvalue()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, data_dir):
    inputs = Inputs(tmp_path_factory.mktemp("inputs"), data_dir)
    with VideoInputs(inputs.dir / "video", data_dir) as inputs.video:
        yield inputs


# -- rows ------------------------------------------------------------------------
def loads_model(data):
    """The model whose file content is ``data``."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "model.npz"
        path.write_bytes(data)
        return load_model(path)


def bad_file_rows(verb, kind, argv):
    """Missing, empty, random, truncated and folder versions of one input of a verb."""
    ext = {"image": ".jpg", "model": ".npz", "config": ".toml", "annotations": ".json"}[kind]
    problems = {
        "image": ("not found", "empty", "as an image", "as an image|damaged", "folder"),
        "model": ("not found", "not a readable", "not a readable", "not a readable", "folder"),
        "config": ("not found", None, "not valid TOML", "not valid TOML", "folder"),
        "annotations": ("not found", "not valid JSON", "not valid JSON", "not valid JSON",
                        "folder"),
    }[kind]
    rows = []
    for (fault, name), problem in zip((("missing", "missing"), ("empty", "empty"),
                                       ("random bytes", "random"), ("truncated", "truncated"),
                                       ("a folder", "folder")), problems):
        path_of = (lambda i, o, n=name: i / f"{n}{ext}")
        if problem is None:  # an empty config is a valid one: the defaults
            rows.append(Row(verb, f"{kind} {fault}", lambda i, o, p=path_of: argv(p(i, o), i, o),
                            code=0))
            continue
        rows.append(Row(verb, f"{kind} {fault}", lambda i, o, p=path_of: argv(p(i, o), i, o),
                        names=path_of, problem=problem))
    return rows


def boxes_of(stdout):
    return json.loads(stdout.splitlines()[-1])["boxes"]


ROWS = [
    # ---- detect -------------------------------------------------------------------
    *bad_file_rows("detect", "image", lambda p, i, o: ["detect", s(p)]),
    Row("detect", "grey PNG", lambda i, o: ["detect", s(i / "grey.png")], code=0),
    Row("detect", "RGBA PNG", lambda i, o: ["detect", s(i / "rgba.png")], code=0),
    Row("detect", "16-bit PNG", lambda i, o: ["detect", s(i / "deep.png")], code=0),
    Row("detect", "image smaller than a window", lambda i, o: ["detect", s(i / "tiny.png")],
        code=0),
    Row("detect", "8K image", lambda i, o: ["detect", s(i / "huge.jpg")], code=0,
        check=lambda i, o, out: boxes_of(out)),
    Row("detect", "image whose header claims 40000x40000 pixels",
        lambda i, o: ["detect", s(i / "claims_huge.png")],
        names=lambda i, o: i / "claims_huge.png", problem="more pixels than OpenCV decodes"),
    Row("detect", "a missing image after good ones (refused before any is searched)",
        lambda i, o: ["detect", s(i.image), s(i / "missing.jpg"), "--out-dir", s(o / "d")],
        names=lambda i, o: i / "missing.jpg", problem="not found",
        guarded=lambda i, o: [o / "d"]),
    *bad_file_rows("detect", "model",
                   lambda p, i, o: ["detect", s(i.image), "--model", s(p)]),
    Row("detect", "model tampered with",
        lambda i, o: ["detect", s(i.image), "--model", s(i / "tampered.npz")],
        names=lambda i, o: i / "tampered.npz", problem="checksum"),
    Row("detect", "model of mismatched length",
        lambda i, o: ["detect", s(i.image), "--model", s(i / "mismatched.npz")],
        names=lambda i, o: i / "mismatched.npz", problem="shape"),
    Row("detect", "model of a future format",
        lambda i, o: ["detect", s(i.image), "--model", s(i / "future.npz")],
        names=lambda i, o: i / "future.npz", problem="version"),
    *bad_file_rows("detect", "config",
                   lambda p, i, o: ["detect", s(i.image), "--config", s(p)]),
    Row("detect", "config with an unknown key",
        lambda i, o: ["detect", s(i.image), "--config", s(i / "unknown.toml")],
        names=lambda i, o: i / "unknown.toml", problem="unknown key.*threshold"),
    Row("detect", "config value of the wrong type",
        lambda i, o: ["detect", s(i.image), "--config", s(i / "wrong_type.toml")],
        names=lambda i, o: i / "wrong_type.toml",
        problem="heat.threshold must be a finite number"),
    Row("detect", "--out-dir read-only",
        lambda i, o: ["detect", s(i.image), "--out-dir", s(o)],
        names=lambda i, o: o, problem="Read-only file system|not writable",
        guarded=lambda i, o: [o / "image.jpg"], setup=lambda i, o: read_only_out(o)),
    Row("detect", "--out-dir on a full disk",
        lambda i, o: ["detect", s(i.image), "--out-dir", s(o / "disk")],
        names=lambda i, o: o / "disk" / "image.jpg", problem="No space left|disk full",
        guarded=lambda i, o: [o / "disk" / "image.jpg", o / "disk" / "previous"],
        setup=lambda i, o: full_disk(o)),
    Row("detect", "--out-dir is the input's folder",
        lambda i, o: ["detect", s(i.image), "--out-dir", s(i.dir)],
        names=lambda i, o: i.image, problem="it is the input",
        guarded=lambda i, o: [i.image]),
    Row("detect", "--out-dir is a file",
        lambda i, o: ["detect", s(i.image), "--out-dir", s(i / "grey.png")],
        names=lambda i, o: i / "grey.png", problem="not a folder",
        guarded=lambda i, o: [i / "grey.png"]),
    Row("detect", "--out-dir holds a symlink named like the output",
        lambda i, o: (os.symlink(o.parent / "outside.jpg", o / "image.jpg"),
                      ["detect", s(i.image), "--out-dir", s(o)])[1],
        names=lambda i, o: o / "image.jpg", problem="symbolic link",
        guarded=lambda i, o: [o.parent / "outside.jpg"]),
    Row("detect", "image name not UTF-8, drawn to --out-dir",
        lambda i, o: (shutil.copy(i.image, o / os.fsdecode(b"car\xff.jpg")),
                      ["detect", s(o / os.fsdecode(b"car\xff.jpg")), "--out-dir",
                       s(o / "d")])[1], code=0,
        check=lambda i, o, out: (o / "d" / os.fsdecode(b"car\xff.jpg")).is_file()),
    Row("detect", "two images of one name for one --out-dir",
        lambda i, o: (os.makedirs(o / "a", exist_ok=True), shutil.copy(i.image, o / "a"),
                      ["detect", s(i.image), s(o / "a" / "image.jpg"), "--out-dir",
                       s(o / "d")])[-1],
        names=lambda i, o: o / "d" / "image.jpg", problem="would both be drawn to"),
    # ---- eval ---------------------------------------------------------------------
    *bad_file_rows("eval", "annotations", lambda p, i, o: ["eval", s(p), s(i.dir)]),
    Row("eval", "annotations of the wrong structure",
        lambda i, o: ["eval", s(i / "wrong.json"), s(i.dir)],
        names=lambda i, o: i / "wrong.json", problem="images"),
    Row("eval", "image folder missing",
        lambda i, o: ["eval", s(i.annotations), s(i / "missing")],
        names=lambda i, o: i / "missing", problem="no such folder"),
    Row("eval", "annotated image truncated",
        lambda i, o: ["eval", s(i / "damaged_image.json"), s(i.dir)],
        names=lambda i, o: i / "truncated.jpg", problem="as an image|damaged"),
    Row("eval", "model tampered with",
        lambda i, o: ["eval", s(i.annotations), s(i.dir), "--model", s(i / "tampered.npz")],
        names=lambda i, o: i / "tampered.npz", problem="checksum"),
    Row("eval", "--iou not a number",
        lambda i, o: ["eval", s(i.annotations), s(i.dir), "--iou", "nan"],
        names=lambda i, o: "nan", problem="--iou must be in"),
    Row("eval", "a vehicle id twice in one frame",
        lambda i, o: ((o / "ids.json").write_text(
            '{"images": {"frame0": [{"box": [0, 0, 9, 9], "id": 1},'
            ' {"box": [20, 0, 29, 9], "id": 1}]}}'), ["eval", s(o / "ids.json"), s(i.dir)])[1],
        names=lambda i, o: o / "ids.json", problem="an id names one vehicle a frame"),
    Row("eval", "annotations that name no image",
        lambda i, o: ((o / "none.json").write_text('{"images": {}}'),
                      ["eval", s(o / "none.json"), s(i.dir)])[1],
        names=lambda i, o: o / "none.json", problem="nothing to evaluate"),
    Row("eval", "a JSON key given twice",
        lambda i, o: ((o / "twice.json").write_text(
            '{"images": {"image.jpg": [], "image.jpg": []}}'),
            ["eval", s(o / "twice.json"), s(i.dir)])[1],
        names=lambda i, o: o / "twice.json", problem="given twice"),
    Row("eval", "annotated image", lambda i, o: ["eval", s(i.annotations), s(i.dir)], code=0),
    # ---- train --------------------------------------------------------------------
    Row("train", "data folder missing",
        lambda i, o: ["train", s(i / "missing"), "--out", s(o / "m.npz")],
        names=lambda i, o: i / "missing", problem="not found"),
    Row("train", "data folder is a file",
        lambda i, o: ["train", s(i.image), "--out", s(o / "m.npz")],
        names=lambda i, o: i.image, problem="not found"),
    Row("train", "data folder without images",
        lambda i, o: ["train", s(i / "empty_data"), "--out", s(o / "m.npz")],
        names=lambda i, o: i / "empty_data", problem="no PNG/JPG"),
    Row("train", "a damaged crop",
        lambda i, o: ["train", s(i.damaged_data), "--out", s(o / "m.npz"), "--no-jitter"],
        names=lambda i, o: i.damaged_data / "vehicles" / "GTI_Far" / "image0007.png",
        problem="as an image", guarded=lambda i, o: [o / "m.npz"]),
]

#: Options that make training on the synthetic crops take a second.
QUICK = ["--no-flip", "--no-jitter", "--spatial-size", "16", "--hist-bins", "16"]


def train_to(out, **row):
    return Row("train", row.pop("fault"), lambda i, o: ["train", s(i.data), "--out",
                                                         s(out(i, o)), *QUICK], **row)


ROWS += [
    train_to(lambda i, o: o / "m.npz", fault="--out in a read-only folder",
             names=lambda i, o: o / "m.npz", problem="not writable",
             guarded=lambda i, o: [o / "m.npz"], setup=lambda i, o: read_only_out(o)),
    train_to(lambda i, o: i.data / "vehicles" / "m.npz", fault="--out inside the training data",
             names=lambda i, o: i.data / "vehicles" / "m.npz",
             problem="inside the training data folder",
             guarded=lambda i, o: [i.data / "vehicles" / "m.npz"]),
    train_to(lambda i, o: o / "missing" / "m.npz", fault="--out in a missing folder",
             names=lambda i, o: o / "missing" / "m.npz", problem="not found"),
    train_to(lambda i, o: o, fault="--out is a folder", names=lambda i, o: o,
             problem="directory"),
    train_to(lambda i, o: o / "disk" / "previous", fault="--out on a full disk",
             names=lambda i, o: o / "disk" / "previous", problem="No space left",
             guarded=lambda i, o: [o / "disk" / "previous"], setup=lambda i, o: full_disk(o)),
    train_to(lambda i, o: i.device("full"), fault="--out a full device (/dev/full)",
             names=lambda i, o: i.full, problem="No space left",
             check=lambda i, o, out: stat.S_ISCHR(os.stat(i.full).st_mode)),
    train_to(lambda i, o: i.device("null"), fault="--out a null device (/dev/null)", code=0,
             check=lambda i, o, out: stat.S_ISCHR(os.stat(i.null).st_mode)),
    train_to(lambda i, o: "-", fault="--out - (stdout)", code=0, subprocess=True,
             messages="^(feature length|accuracy: |model written to -)",
             check=lambda i, o, out: loads_model(out).report["crops"] == 60),
    train_to(lambda i, o: o / "latest.npz", fault="--out is a symlink (followed)", code=0,
             setup=lambda i, o: contextlib.nullcontext(
                 os.symlink(o / "real.npz", o / "latest.npz")),
             check=lambda i, o, out: (o / "latest.npz").is_symlink()
             and load_model(o / "real.npz").report["crops"] == 60),
    Row("train", "invalid option",
        lambda i, o: ["train", s(i.data), "--out", s(o / "m.npz"), "--pixels-per-cell", "7"],
        problem="pixels_per_cell"),
]

_FIFO = []
ROWS += [
    train_to(lambda i, o: o / "model.fifo", fault="--out is a FIFO (written through)", code=0,
             setup=lambda i, o: fifo_reader(o / "model.fifo", _FIFO),
             check=lambda i, o, out: stat.S_ISFIFO(os.stat(o / "model.fifo").st_mode)
             and loads_model(_FIFO[-1]).report["crops"] == 60),
    # ---- mine ---------------------------------------------------------------------
    Row("mine", "source missing",
        lambda i, o: ["mine", s(i / "missing.jpg"), "--annotations", s(i.annotations),
                      "--out", s(o)], names=lambda i, o: i / "missing.jpg", problem="not found"),
    Row("mine", "source random bytes",
        lambda i, o: ["mine", s(i / "random.jpg"), "--annotations",
                      s(i.file("random_annotated.json",
                               b'{"images": {"random.jpg": []}}')), "--out", s(o)],
        names=lambda i, o: i / "random.jpg", problem="as an image"),
    Row("mine", "annotations random bytes",
        lambda i, o: ["mine", s(i.image), "--annotations", s(i / "random.json"), "--out", s(o)],
        names=lambda i, o: i / "random.json", problem="not valid JSON"),
    Row("mine", "--out is a file",
        lambda i, o: ["mine", s(i.image), "--annotations", s(i.annotations), "--out",
                      s(i / "grey.png")],
        names=lambda i, o: i / "grey.png", problem="not a folder",
        guarded=lambda i, o: [i / "grey.png"]),
    Row("mine", "--out read-only",
        lambda i, o: ["mine", s(i.image), "--annotations", s(i.annotations), "--out", s(o)],
        names=lambda i, o: o, problem="Read-only file system|Permission denied",
        setup=lambda i, o: read_only_out(o)),
    Row("mine", "--out on a full disk",
        lambda i, o: ["mine", s(i.image), "--annotations", s(i.annotations), "--out",
                      s(o / "disk")],
        names=lambda i, o: o / "disk", problem="No space left",
        guarded=lambda i, o: [o / "disk" / "previous"], setup=lambda i, o: full_disk(o)),
    Row("mine", "annotated image", lambda i, o: ["mine", s(i.image), "--annotations",
                                                 s(i.annotations), "--out", s(o)], code=0,
        check=lambda i, o, out: all(cv2.imread(str(p)) is not None for p in o.iterdir())),
    # ---- tune ---------------------------------------------------------------------
    Row("tune", "annotations random bytes",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i / "random.json")],
        names=lambda i, o: i / "random.json", problem="not valid JSON"),
    Row("tune", "source truncated",
        lambda i, o: ["tune", s(i / "truncated.jpg"), "--annotations",
                      s(i / "damaged_image.json")],
        names=lambda i, o: i / "truncated.jpg", problem="as an image|damaged"),
    Row("tune", "config random bytes",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i.annotations), "--config",
                      s(i / "random.toml")],
        names=lambda i, o: i / "random.toml", problem="not valid TOML"),
    Row("tune", "--out is the --config",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i.annotations), "--config",
                      s(i / "empty.toml"), "--out", s(i / "empty.toml")],
        names=lambda i, o: i / "empty.toml", problem="it is the input",
        guarded=lambda i, o: [i / "empty.toml"]),
    Row("tune", "--out in a read-only folder",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i.annotations), "--out",
                      s(o / "best.toml")],
        names=lambda i, o: o / "best.toml", problem="not writable",
        setup=lambda i, o: read_only_out(o)),
    Row("tune", "--out on a full disk",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i.annotations), "--out",
                      s(o / "disk" / "previous"), "--top", "1"],
        names=lambda i, o: o / "disk" / "previous", problem="No space left",
        guarded=lambda i, o: [o / "disk" / "previous"],
        setup=lambda i, o: full_disk(o, 16 * 1024 - 10)),
    Row("tune", "--out a full device (/dev/full)",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i.annotations), "--out",
                      s(i.device("full")), "--top", "1"],
        names=lambda i, o: i.full, problem="No space left"),
    Row("tune", "--out - (stdout)",
        lambda i, o: ["tune", s(i.image), "--annotations", s(i.annotations), "--out", "-",
                      "--top", "1"], code=0, subprocess=True,
        messages=r"^(\||best thresholds written to -)",
        check=lambda i, o, out: "[search]" in out.decode() and "|" not in out.decode()),
    # ---- viz ----------------------------------------------------------------------
    Row("viz", "hog: image missing",
        lambda i, o: ["viz", "hog", s(i / "missing.jpg"), "--out", s(o / "h.png")],
        names=lambda i, o: i / "missing.jpg", problem="not found"),
    Row("viz", "hog: image random bytes",
        lambda i, o: ["viz", "hog", s(i / "random.jpg"), "--out", s(o / "h.png")],
        names=lambda i, o: i / "random.jpg", problem="as an image"),
    Row("viz", "hog: image truncated",
        lambda i, o: ["viz", "hog", s(i / "truncated.jpg"), "--out", s(o / "h.png")],
        names=lambda i, o: i / "truncated.jpg", problem="as an image|damaged"),
    Row("viz", "hog: --out is the input",
        lambda i, o: ["viz", "hog", s(i / "grey.png"), "--out", s(i / "grey.png")],
        names=lambda i, o: i / "grey.png", problem="it is the input",
        guarded=lambda i, o: [i / "grey.png"]),
    Row("viz", "hog: --out in a read-only folder",
        lambda i, o: ["viz", "hog", s(i.image), "--out", s(o / "h.png")],
        names=lambda i, o: o / "h.png", problem="Read-only file system|Permission denied",
        guarded=lambda i, o: [o / "h.png"], setup=lambda i, o: read_only_out(o)),
    Row("viz", "hog: --out on a full disk",
        lambda i, o: ["viz", "hog", s(i.image), "--out", s(o / "disk" / "h.png")],
        names=lambda i, o: o / "disk" / "h.png", problem="No space left",
        guarded=lambda i, o: [o / "disk" / "h.png", o / "disk" / "previous"],
        setup=lambda i, o: full_disk(o)),
    Row("viz", "hog: --out with an unknown suffix",
        lambda i, o: ["viz", "hog", s(i.image), "--out", s(o / "h.xyz")],
        names=lambda i, o: o / "h.xyz", problem="must end in"),
    Row("viz", "hog: --out a device (no suffix)",
        lambda i, o: ["viz", "hog", s(i.image), "--out", s(i.device("full"))],
        names=lambda i, o: i.full, problem="must end in"),
    Row("viz", "samples: data folder missing",
        lambda i, o: ["viz", "samples", s(i / "missing"), "--out", s(o / "s.png")],
        names=lambda i, o: i / "missing", problem="not found"),
    Row("viz", "windows: image smaller than every window",
        lambda i, o: ["viz", "windows", s(i / "tiny.png"), "--out", s(o / "w.png"),
                      "--config", s(i.file("one_scale.toml", b"[[search.scales]]\nwindow = 64\n"
                                                           b"overlap = 0.5\nx = [0, 1280]\n"
                                                           b"y = [0, 720]\n"
                                                           b"[search]\nreference_size = "
                                                           b"[10, 10]\n"))],
        names=lambda i, o: i / "tiny.png", problem="smaller than every search window"),
    Row("viz", "detect: annotations random bytes",
        lambda i, o: ["viz", "detect", s(i.image), "--annotations", s(i / "random.json"),
                      "--out", s(o / "d.png")],
        names=lambda i, o: i / "random.json", problem="not valid JSON"),
]


# -- the matrix ----------------------------------------------------------------------
ALL_ROWS = ROWS + VIDEO_ROWS + BATCH_ROWS


@pytest.mark.parametrize("row", ALL_ROWS, ids=lambda row: row.id)
def test_row(row, inputs, tmp_path, capfd):
    check_row(row, inputs, tmp_path, capfd)


def test_debug_shows_the_traceback(inputs):
    from fastdet.errors import InputError

    with pytest.raises(InputError, match="not found"):
        main(["--debug", "detect", s(inputs / "missing.jpg")])
    with pytest.raises(InputError, match="not found"):
        main(["detect", s(inputs / "missing.jpg"), "--debug"])


def test_every_verb_that_reads_or_writes_has_rows():
    verbs = {row.verb for row in ALL_ROWS}
    assert {"detect", "eval", "train", "mine", "tune", "viz", "run"} <= verbs


def test_the_documented_table_is_the_matrix():
    """``docs/reliability.md`` lists every row, as run (``print_table`` below writes it)."""
    text = (ROOT / "docs" / "reliability.md").read_text()
    start = text.index(TABLE_HEADER[0])
    end = text.find("\n\n", start)
    assert text[start:end if end >= 0 else None].rstrip("\n") == markdown_table(ALL_ROWS)


def print_table():
    """Print the table for ``docs/reliability.md``: ``python tests/reliability/test_matrix.py``."""
    print(markdown_table(ALL_ROWS))


if __name__ == "__main__":
    print_table()
