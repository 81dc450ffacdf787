"""Issue 38: every file kind fgcal reads has one typed schema, published as JSON Schema
(``fgcal schema KIND``, shipped in fgcal/schemas/). The JSON Schemas hold every bundled file,
every config in docs/ and README.md and the files fgcal writes for itself to read (simulate,
import-csv, convert-faro, a calibrated robot); bad documents are refused by the JSON Schema and
by fgcal alike, fgcal naming the file and the field (exit 2). Null is a value: it means off only
where a field documents it (a robust loss), and is refused elsewhere (a section)."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import jsonschema
import pytest
import yaml
from conftest import REPO, SHARED

from fgcal.commands.cli import main
from fgcal.commands.schema import KINDS, schema_text, shipped_text

FARO = SHARED / "data" / "irb120_faro"
DOCS = [*sorted((REPO / "docs").glob("*.md")), REPO / "README.md"]
# A documented block that is part of a config starts with this comment (docs/calibration.md).
PART = re.compile(r"#\s*part of an? (\w+) (?:config|file|mapping|setup)")
# YAML blocks of the docs that show a file no schema of KINDS describes, by their format.
OTHER_FORMATS = {"fgcal-estimates/1"}  # estimates.yaml, read by fgcal compensate --estimates


def _validator(kind: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator(json.loads(schema_text(kind)))


def _errors(kind: str, document: object, partial: bool = False) -> list[str]:
    schema = json.loads(schema_text(kind))
    if partial:  # a part of a document: what it states must hold, what it leaves out may be missing
        schema.pop("required", None)
    validator = jsonschema.Draft202012Validator(schema)
    return [f"{'.'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(document)]


@pytest.mark.parametrize("kind", KINDS)
def test_the_shipped_schema_is_what_fgcal_schema_prints(kind, capsys):
    """The JSON Schemas in the package never go stale (regenerate: fgcal schema KIND >
    fgcal/schemas/KIND.schema.json), and each is a valid JSON Schema (draft 2020-12)."""
    assert main(["schema", kind]) == 0
    printed = capsys.readouterr().out
    assert printed == schema_text(kind) == shipped_text(kind), f"fgcal schema {kind} > fgcal/schemas/{kind}.schema.json"
    schema = json.loads(printed)
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["additionalProperties"] is False and schema["properties"]


def test_an_unknown_kind_is_one_line_and_exit_2(capsys):
    assert main(["schema", "robots"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("fgcal: error: ") and "\n" not in error and "calibration" in error, error


def _bundled() -> list[tuple[str, Path]]:
    robots = sorted((REPO / "datasets" / "robots").glob("*.yaml"))
    cells = sorted((REPO / "datasets" / "cells").glob("*.yaml"))
    return [("robot", p) for p in robots] + [("cell", p) for p in cells]


@pytest.mark.parametrize(("kind", "path"), _bundled(), ids=[p.name for _, p in _bundled()])
def test_every_bundled_file_holds_its_schema(kind, path):
    assert not _errors(kind, yaml.safe_load(path.read_text(encoding="utf-8")))


def test_the_bundle_is_all_there():
    """Every YAML file in datasets/ is a robot or a cell (a new kind would need its schema here)."""
    assert {p for _, p in _bundled()} == set((REPO / "datasets").rglob("*.yaml"))
    assert len(_bundled()) >= 15


def _kind(document: dict) -> str | None:
    """The kind of a documented block, by what it states."""
    formats = {"fgcal-dataset/1": "dataset", "fgcal-import/1": "import"}
    if "format" in document:
        return formats.get(document["format"])
    if "joints" in document and "source" in document:
        return "robot"
    if "robot" in document and "name" in document:
        return "cell"
    if "dataset" in document:
        return "online" if {"settings", "released", "target_accuracy_m"} & set(document) else "calibration"
    return None


def _doc_blocks() -> list[tuple[str, str]]:
    blocks = []
    for path in DOCS:
        text = path.read_text(encoding="utf-8")
        for match in re.finditer(r"```ya?ml\n(.*?)```", text, re.S):
            line = text[: match.start()].count("\n") + 1
            blocks.append((f"{path.name}:{line}", match.group(1)))
    return blocks


@pytest.mark.parametrize(("where", "block"), _doc_blocks(), ids=[w for w, _ in _doc_blocks()])
def test_every_documented_config_holds_its_schema(where, block):
    """Each YAML block of docs/ and README.md is a whole file of a kind, or says which kind it is
    a part of in its first line (``# part of a calibration config``), or shows a file of another
    format (OTHER_FORMATS); a block none of these fails here."""
    document = yaml.safe_load(block)
    assert isinstance(document, dict), where
    part = PART.match(block.lstrip())
    if part:
        assert part.group(1) in KINDS, (where, part.group(1))
        assert not _errors(part.group(1), document, partial=True), where
        return
    if document.get("format") in OTHER_FORMATS:
        return
    kind = _kind(document)
    assert kind is not None, f"{where}: which file is this block? (say '# part of a KIND config' if a part)"
    assert not _errors(kind, document), (where, kind, _errors(kind, document))


def test_the_docs_show_each_kind():
    shown = {_kind(yaml.safe_load(b)) for _, b in _doc_blocks()} | {
        PART.match(b.lstrip()).group(1) for _, b in _doc_blocks() if PART.match(b.lstrip())
    }
    assert {"calibration", "online", "import"} <= shown, shown


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A small simulated tracker session, as fgcal simulate writes it."""
    out = tmp_path_factory.mktemp("schema_session")
    assert main(["-q", "simulate", "irb120_tracker", "--out", str(out / "session"), "--n", "20"]) == 0
    return out


def test_what_simulate_and_import_csv_write_holds_the_schemas(session, capsys):
    assert not _errors("dataset", yaml.safe_load((session / "session" / "dataset.yaml").read_text()))
    assert not _errors("calibration", yaml.safe_load((session / "session" / "calibration.yaml").read_text()))
    mapping = {
        "format": "fgcal-import/1",
        "robot": "abb_irb120",
        "configurations": {"file": "session/configurations.csv", "config": "config",
                           "joints": [f"q{i}" for i in range(1, 7)]},
        "tracker_points": [{"file": "session/tracker_points.csv", "config": 1, "target": "target",
                            "xyz": ["x", "y", "z"], "zeros_mean_not_found": True}],
    }  # fmt: skip
    assert not _errors("import", mapping)
    (session / "mapping.yaml").write_text(yaml.safe_dump(mapping), encoding="utf-8")
    assert main(["-q", "import-csv", str(session / "mapping.yaml"), "--out", str(session / "imported")]) == 0
    assert not _errors("dataset", yaml.safe_load((session / "imported" / "dataset.yaml").read_text()))
    assert not _errors("calibration", yaml.safe_load((session / "imported" / "calibration.yaml").read_text()))


def test_a_written_robot_holds_the_robot_schema():
    """What fgcal calibrate writes (calibrated_robot.yaml): robot_document, with parameters."""
    from fgcal.model.robot_io import load_robot, robot_document

    for name in ("abb_irb120", "dual_arm_torso", "seven_axis"):
        robot = load_robot(name)
        document = json.loads(json.dumps(robot_document(robot, robot.nominal_parameters(), notes="n")))
        assert not _errors("robot", document), name


@pytest.mark.skipif(not FARO.exists(), reason="../shared/data/irb120_faro is not present")
def test_what_convert_faro_writes_holds_the_schemas(tmp_path):
    from fgcal.data.faro import faro_mapping

    assert not _errors("import", json.loads(json.dumps(faro_mapping(FARO, "abb_irb120"))))
    assert main(["-q", "convert-faro", str(FARO), "--out", str(tmp_path / "faro")]) == 0
    assert not _errors("dataset", yaml.safe_load((tmp_path / "faro" / "dataset.yaml").read_text()))
    assert not _errors("calibration", yaml.safe_load((tmp_path / "faro" / "calibration.yaml").read_text()))


CELL = (REPO / "datasets" / "cells" / "irb120_tracker.yaml").read_text(encoding="utf-8")
ROBOT = (REPO / "datasets" / "robots" / "abb_irb120.yaml").read_text(encoding="utf-8")
# Bad documents: (name, kind, file, text, the fgcal command (FILE: the file), the field named).
BAD = [
    ("config_noise_null", "calibration", "c.yaml", "dataset: data\nnoise: null\n",
     ["calibrate", "FILE", "--out", "o"], "noise"),
    ("config_unknown_key", "calibration", "c.yaml", "dataset: data\nrobust: {tracker_point: [huber, 3]}\n",
     ["calibrate", "FILE", "--out", "o"], "robust.tracker_point"),
    ("config_loss_unknown", "calibration", "c.yaml", "dataset: data\nrobust: {pixels: [tukey, 3]}\n",
     ["calibrate", "FILE", "--out", "o"], "robust.pixels"),
    ("config_seed_text", "calibration", "c.yaml", "dataset: data\nvalidation: {seed: one}\n",
     ["calibrate", "FILE", "--out", "o"], "validation.seed"),
    ("config_stage_kind", "calibration", "c.yaml", "dataset: data\nstages: [[theta, zeta]]\n",
     ["calibrate", "FILE", "--out", "o"], "stages[0]"),
    ("cell_unknown_key", "cell", "cell.yaml", CELL + "\ntracker_noise: 3\n", ["simulate", "FILE", "--out", "o"],
     "tracker_noise"),
    ("cell_design_count_text", "cell", "cell.yaml", CELL.replace("n_configurations: 100", "n_configurations: many"),
     ["simulate", "FILE", "--out", "o"], "design.n_configurations"),
    ("robot_mass_negative", "robot", "robot.yaml", ROBOT.replace("mass: 3.067", "mass: -3.067"),
     ["fk", "FILE", "0", "0", "0", "0", "0", "0"], "joints[0].mass"),
    ("robot_gravity_short", "robot", "robot.yaml", ROBOT.replace("gravity: [0, 0, -9.81]", "gravity: [0, -9.81]"),
     ["fk", "FILE", "0", "0", "0", "0", "0", "0"], "gravity"),
    ("robot_units_null", "robot", "robot.yaml", ROBOT.replace("units: {length: mm, angle: deg}", "units: null"),
     ["fk", "FILE", "0", "0", "0", "0", "0", "0"], "units"),
    ("import_read_key", "import", "m.yaml", "format: fgcal-import/1\nrobot: abb_irb120\nconfigurations: {file: a.csv, "
     "joints: [1, 2, 3, 4, 5, 6], delimter: ';'}\n", ["import-csv", "FILE", "--out", "o"], "configurations.delimter"),
    ("import_format", "import", "m.yaml", "format: fgcal-import/2\nrobot: abb_irb120\nconfigurations: {file: a.csv, "
     "joints: [1, 2, 3, 4, 5, 6]}\n", ["import-csv", "FILE", "--out", "o"], "format"),
]  # fmt: skip


@pytest.mark.parametrize(("kind", "name", "text", "argv", "field"), [c[1:] for c in BAD], ids=[c[0] for c in BAD])
def test_a_bad_document_is_refused_by_its_schema_and_by_fgcal(kind, name, text, argv, field, tmp_path, capsys,
                                                                monkeypatch):  # fmt: skip
    assert _errors(kind, yaml.safe_load(text)), "the JSON Schema lets it through"
    monkeypatch.chdir(tmp_path)
    (tmp_path / name).write_text(text, encoding="utf-8")
    assert main([a.replace("FILE", name) for a in argv]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("fgcal: error: ") and "\n" not in error and "Traceback" not in error, error
    assert f"{name}: {field}" in error, error


def test_a_bad_dataset_header_is_refused_naming_the_field(session, tmp_path, capsys):
    import shutil

    shutil.copytree(session / "session", tmp_path / "data")
    header = yaml.safe_load((tmp_path / "data" / "dataset.yaml").read_text())
    header["order"] = "sometimes"
    assert _errors("dataset", header)
    (tmp_path / "data" / "dataset.yaml").write_text(yaml.safe_dump(header), encoding="utf-8")
    (tmp_path / "c.yaml").write_text("dataset: data\n", encoding="utf-8")
    assert main(["calibrate", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "o"), "--no-plots"]) == 2
    error = capsys.readouterr().err.strip()
    assert "dataset.yaml: order: 'sometimes' is not one of measured, unknown" in error, error


def test_null_is_off_where_documented_and_refused_elsewhere(tmp_path):
    """``robust: {tracker_points: null}`` is no robust loss (as none); ``noise: null`` is
    refused, by fgcal and by the JSON Schema (a section given as null is never its defaults)."""
    from fgcal.calibration.config import parse_config
    from fgcal.core.errors import InputError

    off = {"dataset": "data", "robust": {"tracker_points": None, "pixels": "none"}}
    assert not _errors("calibration", off)
    config = parse_config(off, tmp_path / "c.yaml")
    assert config.measurement.robust["tracker_points"] is None and config.measurement.robust["pixels"] is None
    assert config.measurement.robust["distances"] == ("huber", 3.0)
    for bad, field in (({"noise": None}, "noise"), ({"robust": None}, "robust"),
                       ({"noise": {"tracker_sigma": None}}, "noise.tracker_sigma"),
                       ({"validation": {"holdout": None}}, "validation.holdout")):  # fmt: skip
        document = {"dataset": "data", **bad}
        assert _errors("calibration", document), bad
        with pytest.raises(InputError, match=rf"c\.yaml: {re.escape(field)}: is null"):
            parse_config(document, tmp_path / "c.yaml")


def test_the_online_settings_schema_is_the_calibrators():
    """The setup's settings are OnlineSettings' fields, no more and no fewer."""
    from fgcal.online.calibrator import OnlineSettings
    from fgcal.online.schema import Settings

    assert list(Settings.model_fields) == [f.name for f in dataclasses.fields(OnlineSettings)]


def test_plain_numbers_yaml_reads_as_text_are_numbers_for_both():
    """YAML 1.1 (PyYAML) reads 1e-5 as text; fgcal reads it as the number, and so does the
    JSON Schema (an editor's YAML 1.2 reads it as a number anyway)."""
    from fgcal.calibration.config import parse_config

    document = yaml.safe_load("dataset: data\nnoise: {tracker_sigma: 1e-5}\n")
    assert document["noise"]["tracker_sigma"] == "1e-5"
    assert not _errors("calibration", document)
    assert parse_config(document, Path("c.yaml")).noise.tracker_m == pytest.approx(1e-5)
    assert _errors("calibration", {"dataset": "data", "noise": {"tracker_sigma": "1e-5 m"}})
