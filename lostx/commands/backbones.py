"""``lostx backbones``: the semantic backbones; ``inspect`` a model's tensors; ``export-onnx`` ESPNetv2."""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIBED = ("tflite", "onnx")
"""The generic backbones: each takes a model file of its own name's suffix, described by a TOML file."""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("backbones", help="list the semantic backbones; inspect a model; export ESPNetv2 to ONNX",
                            description="Without a verb: list the backbones and their default model files.")
    parser.set_defaults(run=run_list)
    verbs = parser.add_subparsers(dest="verb", metavar="VERB")

    inspect = verbs.add_parser("inspect", help="list a .tflite or .onnx model's tensors and suggest the feature "
                                               "and score tensors for its description")
    inspect.add_argument("model", type=Path, help=".tflite or .onnx file")
    inspect.add_argument("--all", action="store_true", help="list every activation, not only the maps")
    inspect.set_defaults(run=run_inspect)

    export = verbs.add_parser("export-onnx", help="export the ESPNetv2 network to ONNX, with its description")
    export.add_argument("--model", type=Path, help="ESPNetv2 Cityscapes weights (default: in the models folder)")
    export.add_argument("--out", type=Path, required=True, help="the .onnx file to write (its .toml goes beside it)")
    export.add_argument("--overwrite", action="store_true", help="replace existing files")
    export.set_defaults(run=run_export)


def run_list(args: argparse.Namespace) -> int:
    from lostx.core.backbones import default_model_paths

    for name, path in default_model_paths().items():
        if path is not None:
            where = f"{path} ({'found' if path.is_file() else 'missing'})"
        elif name in DESCRIBED:
            where = f"--model FILE: a .{name} model with its .toml description beside it, or the .toml"
        else:
            where = "plugin or registered backbone; --model FILE if it takes one"
        print(f"{name:24s} {where}")
    print("also: package.module:factory (a backbone factory of your own; see docs/backbones.md)")
    return 0


def run_inspect(args: argparse.Namespace) -> int:
    from lostx.core.backbones.graph import read_graph, suggest

    graph = read_graph(args.model)
    suggestion = suggest(graph)
    maps = [t for t in graph.activations if graph.map_shape(t) is not None]
    listed = graph.activations if args.all else maps
    width = min(max((len(t.name) for t in listed), default=10), 72)
    print(f"{graph.path}: {graph.runtime}, {graph.layout} layout, {len(graph.activations)} activations "
          f"({len(maps)} maps)")
    for role, tensors in (("input", graph.inputs), ("output", graph.outputs)):
        for t in tensors:
            print(f"{role:7s} {t.name}  {_shape(t.shape)}  {t.dtype}")
    print(f"\n{'tensor':{width}s}  {'shape':>18s}  {'dtype':8s} readers")
    marks = {getattr(suggestion.features, "name", None): "  <- features?", getattr(suggestion.scores, "name", None):
             "  <- scores?"}
    for t in listed:
        print(f"{t.name:{width}s}  {_shape(t.shape):>18s}  {t.dtype:8s} {t.readers:7d}{marks.get(t.name, '')}")
    print("\nsuggested description (check it; add classes = [...] in score-channel order and default_classes):")
    print(f"model = \"{graph.path.name}\"")
    for key, tensor in (("features", suggestion.features), ("scores", suggestion.scores)):
        if tensor is None:
            print(f"# {key}: no tensor looks like it; pick one from the list above")
            continue
        h, w, c = graph.map_shape(tensor)  # type: ignore[misc]
        print(f"{key} = \"{tensor.name}\"  # {c} channels on a {h} x {w} grid")
    return 0


def _shape(shape: tuple[int | None, ...]) -> str:
    return "x".join("?" if v is None else str(v) for v in shape) or "scalar"


def run_export(args: argparse.Namespace) -> int:
    from lostx.core.backbones.registry import missing_package, resolve_model_path
    from lostx.core.config import BackboneConfig
    from lostx.core.outputs import check_output_file

    check_output_file(args.out, "--out")
    weights = resolve_model_path(BackboneConfig(name="espnetv2-cityscapes", model_path=args.model))
    try:
        from lostx.core.backbones.espnet_onnx import export_onnx

        exported = export_onnx(weights, args.out, overwrite=args.overwrite)  # type: ignore[arg-type]
    except ImportError as exc:
        raise missing_package(exc, "export-onnx") from None
    print(f"wrote {exported.model} ({exported.bytes / 1e6:.1f} MB) and {exported.description}; use them with "
          f"--backbone onnx --model {exported.model}")
    return 0
