"""``fgcal schema KIND``: the JSON Schema of a file kind fgcal reads, for an editor's YAML language
server (docs/formats.md, "Schemas"). The same schemas ship in the package (fgcal/schemas/)."""

from __future__ import annotations

import argparse
import json
from importlib import resources


def _kinds() -> dict:
    """KIND -> (model, title, description); each file kind's model is in the layer that owns it."""
    from ..calibration.schema import CalibrationConfig
    from ..data.schema import DatasetHeader, ImportMapping
    from ..model.schema import RobotFile
    from ..online.schema import OnlineSetup
    from ..simulation.schema import CellFile

    return {
        "calibration": (CalibrationConfig, "fgcal calibration config", "fgcal calibrate CONFIG (docs/calibration.md)"),
        "dataset": (DatasetHeader, "fgcal dataset.yaml", "a dataset's header (docs/formats.md)"),
        "robot": (RobotFile, "fgcal robot file", "a robot description (docs/formats.md)"),
        "cell": (CellFile, "fgcal cell", "a simulated cell, fgcal simulate CELL (docs/formats.md)"),
        "online": (OnlineSetup, "fgcal online setup", "fgcal online --setup SETUP (docs/online.md)"),
        "import": (ImportMapping, "fgcal import mapping", "fgcal import-csv MAPPING (docs/formats.md)"),
    }


KINDS = ("calibration", "dataset", "robot", "cell", "online", "import")


def schema_text(kind: str) -> str:
    """The JSON Schema of ``kind`` as ``fgcal schema`` prints it (and fgcal/schemas/ holds it)."""
    from ..core.schema import json_schema

    model, title, description = _kinds()[kind]
    return json.dumps(json_schema(model, title, description), indent=2, ensure_ascii=False) + "\n"


def shipped_text(kind: str) -> str:
    """The JSON Schema of ``kind`` shipped in the package (fgcal/schemas/KIND.schema.json)."""
    return resources.files("fgcal").joinpath("schemas", f"{kind}.schema.json").read_text(encoding="utf-8")


def cmd_schema(args: argparse.Namespace) -> int:
    print(schema_text(args.kind), end="")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "schema",
        help="print the JSON Schema of a file kind (for an editor's YAML language server)",
        description="Print the JSON Schema of a file kind fgcal reads, e.g. "
        "fgcal schema calibration > calibration.schema.json (docs/formats.md, Schemas).",
    )
    p.add_argument("kind", choices=KINDS, help="the file kind: " + ", ".join(KINDS))
    p.set_defaults(func=cmd_schema)
