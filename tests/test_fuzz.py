"""Property-based fuzzing (hypothesis) of the loaders users feed: CSV tables, YAML documents
(calibration config, robot, dataset header) and online measurement files. Whatever the input,
nothing but fgcal's own InputError may escape. Bounded: a few hundred examples each, well
under a minute in all."""

from __future__ import annotations

import contextlib
import copy
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import SEED_CELL
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgcal.calibration.config import parse_config
from fgcal.core.errors import InputError
from fgcal.data.dataset import load_dataset
from fgcal.model.robot_io import parse_robot
from fgcal.online.measurement import parse_measurement, read_measurement

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

# Scalars YAML and JSON produce, with the awkward ones over-represented.
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["1e-4", "nan", "-inf", "0_1", "1_000", "\uff11", "", "mm", "deg", "DH,s,e", "pairs"]),
)
KEYS = [
    "dataset", "formulation", "model", "noise", "camera_point_sigma", "stages", "robust", "pairs", "validation",
    "holdout", "units", "length", "angle", "joints", "name", "d", "a", "alpha", "theta", "limits", "mass", "com",
    "payload", "gravity", "format", "robot", "measured", "files", "camera", "intrinsics", "fx", "pixels", "cycle",
]  # fmt: skip
documents = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=6),
        st.dictionaries(st.one_of(st.sampled_from(KEYS), st.text(max_size=8)), children, max_size=6),
    ),
    max_leaves=30,
)


_DELETE = object()


def _paths(node, prefix=()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for key, value in node.items():
            out += _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _paths(value, (*prefix, i))
    return out


def mutated(template: dict) -> st.SearchStrategy:
    """Near-valid documents: ``template`` with one to three places replaced by anything (or
    deleted), so that the fuzzing reaches deep fields instead of failing at the first key."""
    paths = _paths(template)

    def apply(changes) -> dict:
        doc = copy.deepcopy(template)
        for path, value in changes:
            node = doc
            try:
                for part in path[:-1]:
                    node = node[part]
                if value is _DELETE:
                    del node[path[-1]]
                else:
                    node[path[-1]] = value
            except (KeyError, IndexError, TypeError):
                continue  # an earlier change removed or replaced the way there
        return doc

    change = st.tuples(st.sampled_from(paths), st.one_of(scalars, scalars, documents, st.just(_DELETE)))
    return st.lists(change, min_size=1, max_size=3).map(apply)


CONFIG = {
    "dataset": "data", "formulation": "pairs", "model": "DH,s,e", "compliant_joints": [1, 2, 3],
    "noise": {"camera_point_sigma": 1e-4, "pixel_sigma_px": 0.1}, "stages": [["theta"], ["alpha", "sx", "sy"]],
    "robust": {"pixels": ["huber", 3.0]}, "pairs": {"group_images": 4, "partner": "any"},
    "validation": {"holdout": 0.25, "seed": 0}, "solver": {"method": "lm", "max_iterations": 10},
    "units": {"length": "mm"}, "intrinsics": {"estimate": True, "prior_sigma": {"focal_px": 5}},
}  # fmt: skip
MEASUREMENT = {
    "format": "fgcal-measurement/1", "cycle": 3, "units": {"angle": "deg"},
    "joints": [10.0, -45.0, 80.0, 0.0, 30.0, 0.0], "pixels": {"P1": [812.4, 533.1], "P2": [901.7, 530.2]},
}  # fmt: skip


@FUZZ
@given(doc=st.one_of(documents, mutated(CONFIG)))
def test_calibration_config_fuzz(tmp_path_factory, doc):
    with contextlib.suppress(InputError):
        parse_config(doc, Path("fuzz.yaml"), base_dir=Path("."))


ROBOT = yaml.safe_load((Path(__file__).parents[1] / "datasets" / "robots" / "abb_irb120.yaml").read_text("utf-8"))


@FUZZ
@given(doc=st.one_of(documents, mutated(ROBOT)))
def test_robot_document_fuzz(doc):
    with contextlib.suppress(InputError):
        parse_robot(doc, Path("fuzz_robot.yaml"))


@FUZZ
@given(doc=st.one_of(documents, mutated(MEASUREMENT)), n_joints=st.integers(min_value=5, max_value=7))
def test_measurement_document_fuzz(doc, n_joints):
    with contextlib.suppress(InputError):
        parse_measurement(doc, "m.json", Path("m.json"), n_joints)


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory) -> Path:
    from fgcal.simulation.simulate import simulate

    out = tmp_path_factory.mktemp("fuzz_source")
    simulate(SEED_CELL, out, seed=6)
    return out


cells = st.one_of(
    st.text(alphabet=st.characters(blacklist_categories=["Cs"]), max_size=8),
    st.sampled_from(["1e300", "nan", "-0", "+.5", "1_0", "c0000", "\ufeff", '"', "\r", "0x1p3"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


@FUZZ
@given(
    table=st.sampled_from(
        ["configurations.csv", "points.csv", "camera_points.csv", "pixels.csv", "tracker_points.csv"]
    ),
    rows=st.lists(st.lists(cells, min_size=0, max_size=7), min_size=0, max_size=5),
    keep_header=st.booleans(),
)
def test_csv_table_fuzz(dataset_dir, tmp_path_factory, table, rows, keep_header):
    data = tmp_path_factory.mktemp("fuzz_csv")
    shutil.copytree(dataset_dir, data, dirs_exist_ok=True)
    lines = (data / table).read_text(encoding="utf-8").splitlines()
    body = [",".join(row) for row in rows]
    (data / table).write_text("\n".join(([lines[0]] if keep_header else []) + lines[1:3] + body) + "\n", "utf-8")
    with contextlib.suppress(InputError):
        load_dataset(data)


@FUZZ
@given(content=st.binary(max_size=300) | st.text(max_size=300).map(lambda t: t.encode("utf-8")))
def test_measurement_file_bytes_fuzz(tmp_path_factory, content):
    path = tmp_path_factory.mktemp("fuzz_json") / "m.json"
    path.write_bytes(content)
    with contextlib.suppress(InputError):
        read_measurement(path, 6)


@FUZZ
@given(text=st.text(max_size=200))
def test_yaml_text_fuzz(tmp_path_factory, text):
    from fgcal.core.fields import read_yaml

    path = tmp_path_factory.mktemp("fuzz_yaml") / "doc.yaml"
    path.write_text(text, encoding="utf-8")
    with contextlib.suppress(InputError):
        parse_config(read_yaml(path), path)


@pytest.fixture(scope="module")
def header(dataset_dir) -> dict:
    return yaml.safe_load((dataset_dir / "dataset.yaml").read_text(encoding="utf-8"))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_dataset_header_fuzz(dataset_dir, header, tmp_path_factory, data):
    doc = data.draw(mutated(header))
    folder = tmp_path_factory.mktemp("fuzz_header")
    shutil.copytree(dataset_dir, folder, dirs_exist_ok=True)
    (folder / "dataset.yaml").write_text(yaml.safe_dump(doc), encoding="utf-8")
    with contextlib.suppress(InputError):
        load_dataset(folder)


# The URDF reader: the surfaces test's small URDF with one to four attribute values replaced by
# anything (escaped for XML), or an element dropped.
URDF_TEMPLATE = (
    "<robot name='r'><link name='base'/>"
    "<link name='l1'><inertial><mass value='2'/><origin xyz='0 0 0.1' rpy='0 0 0'/></inertial></link>"
    "<link name='tool0'/>"
    "<joint name='j1' type='revolute'><parent link='base'/><child link='l1'/><origin xyz='0 0 0.3' rpy='0 0 0'/>"
    "<axis xyz='0 0 1'/><limit lower='-3' upper='3' effort='1' velocity='1'/></joint>"
    "<joint name='t' type='fixed'><parent link='l1'/><child link='tool0'/><origin xyz='0.1 0 0'/></joint></robot>"
)
_ATTRIBUTES = [m.span(1) for m in re.finditer(r"='([^']*)'", URDF_TEMPLATE)]
_ELEMENTS = [m.span() for m in re.finditer(r"<(origin|axis|limit|inertial|parent|child|mass)[^>]*/>", URDF_TEMPLATE)]
urdf_values = st.one_of(
    st.sampled_from(["", "nan", "inf", "-1e300", "1e300", "0 0", "0 0 0 0", "1 2 three", "base", "l1", "tool0",
                     "ghost", "prismatic", "continuous", "floating", "planar", "-0", "1e-320"]),
    st.text(max_size=12),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5).map(lambda v: " ".join(map(repr, v))),
)  # fmt: skip


@FUZZ
@given(
    changes=st.lists(st.tuples(st.sampled_from(_ATTRIBUTES), urdf_values), min_size=1, max_size=4),
    dropped=st.lists(st.sampled_from(_ELEMENTS), max_size=2),
    tip=st.sampled_from([None, "tool0", "l1", "base", "ghost"]),
)
def test_urdf_fuzz(tmp_path_factory, changes, dropped, tip):
    from xml.sax.saxutils import escape

    from fgcal.model.robot_io import load_robot

    edits = {span: escape(value, {"'": "&apos;"}) for span, value in changes} | {span: "" for span in dropped}
    text = URDF_TEMPLATE
    for (start, end), value in sorted(edits.items(), reverse=True):  # from the end: spans stay valid
        if not any(s < start < e for s, e in edits if (s, e) != (start, end)):  # no edit inside another
            text = text[:start] + value + text[end:]
    path = tmp_path_factory.mktemp("fuzz_urdf") / "arm.urdf"
    path.write_text(text, encoding="utf-8")
    with contextlib.suppress(InputError):
        robot = load_robot(path, tip)
        robot.fk(np.clip(np.zeros(robot.n_joints), robot.limits[:, 0], robot.limits[:, 1]))


# The importer's mapping: a valid mapping of two exports with one to three places changed.
MAPPING = {
    "format": "fgcal-import/1", "robot": "abb_irb120", "units": {"length": "mm", "angle": "deg"},
    "configurations": {"file": "controller.csv", "config": "pose", "joints": ["A1", "A2", "A3", "A4", "A5", "A6"],
                       "skip_rows": 0, "delimiter": ",", "decimal": "."},
    "tracker_points": {"file": "tracker.csv", "config": "pose", "target": "name", "xyz": ["x", "y", "z"],
                       "not_found": [""], "units": {"length": "mm"}},
    "payload": {"mass": 0.5, "com": [0, 0, 30]}, "source": "fuzz",
}  # fmt: skip


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz_exports")
    rng = np.random.default_rng(1)
    lines = ["pose,A1,A2,A3,A4,A5,A6"] + [
        ",".join([f"P{i}", *(repr(float(v)) for v in rng.uniform(-40, 40, 6))]) for i in range(8)
    ]
    (folder / "controller.csv").write_text("\n".join(lines) + "\n")
    lines = ["pose,name,x,y,z"] + [
        ",".join([f"P{i}", "t1", *(repr(float(v)) for v in rng.uniform(-900, 900, 3))]) for i in range(8)
    ]
    (folder / "tracker.csv").write_text("\n".join(lines) + "\n")
    return folder


@FUZZ
@given(doc=st.one_of(documents, mutated(MAPPING)))
def test_import_mapping_fuzz(exports, tmp_path_factory, doc):
    from fgcal.data.csv_import import import_mapping

    out = tmp_path_factory.mktemp("fuzz_imported")
    with contextlib.suppress(InputError):
        import_mapping(doc, exports / "mapping.yaml", exports, out / "dataset", "fuzz")
