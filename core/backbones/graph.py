"""A model file's tensors, and which look like the deep features and the class scores (``lostx backbones inspect``).

Only activations are listed (tensors an operation produces), never weights, so
a bias constant can not pass for a feature map. The suggestions are a start
for a description, to be checked:

* scores: the model's last map with at most 255 channels (a graph output where
  there is one), followed back through the resizes that only upsample it;
* features: a map at 1/8 to 1/32 of the input with at least 64 channels: a
  graph output where there is one, else the one most operations read (the
  encoder's last map feeds every branch of the decoder's pyramid pooling),
  the widest of those, the latest of those. Where that map is a linear
  projection (a MobileNetV2 block's last 1x1 convolution, without an
  activation), the latest activation output on the same grid before it is
  suggested instead: LoST's keypoints and descriptors come from post-ReLU
  features (the paper's conv5). An activation is an operation such as ReLU, ReLU6,
  sigmoid or hard-swish, or one fused with it (TFLite names the fused
  tensor after it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import ModelError
from .description import Layout

RESIZES = {"RESIZE_BILINEAR", "RESIZE_NEAREST_NEIGHBOR", "Resize", "Upsample"}
MAX_CLASSES = 255
"""Labels are stored as uint8."""
ACTIVATIONS = {
    "RELU", "RELU6", "RELU_N1_TO_1", "RELU_0_TO_1", "LEAKY_RELU", "PRELU", "LOGISTIC", "TANH", "HARD_SWISH", "GELU",
    "ELU", "Relu", "Clip", "PRelu", "LeakyRelu", "Sigmoid", "HardSigmoid", "HardSwish", "Elu", "Selu", "Celu", "Gelu",
    "Mish", "Tanh", "Softplus", "ThresholdedRelu", "Swish",
}
"""Operations (TFLite's and ONNX's) whose output is a nonlinearity's."""
ACTIVATION_NAME = re.compile(
    r"(relu6?|relu_?n1_?to_?1|leaky_?relu|prelu|sigmoid|logistic|hard_?swish|swish|silu|gelu|elu|selu|tanh|mish|"
    r"clip_by_value)(_\d+)?", re.IGNORECASE)
"""The last part of a tensor name that says an activation was fused into the operation that produced it."""


@dataclass(frozen=True)
class GraphTensor:
    name: str
    """The name a description uses for it."""
    shape: tuple[int | None, ...]
    dtype: str
    readers: int = 0
    """Operations that take it as an input."""
    activation: bool = False
    """Produced by an activation, or by an operation fused with one."""


@dataclass(frozen=True)
class ModelGraph:
    path: Path
    runtime: Literal["tflite", "onnx"]
    layout: Layout
    inputs: list[GraphTensor]
    outputs: list[GraphTensor]
    activations: list[GraphTensor]
    """Tensors produced by an operation, in execution order."""
    producers: dict[str, tuple[str, str]]
    """Tensor name -> (operation kind, its first input's name)."""

    def map_shape(self, tensor: GraphTensor) -> tuple[int, int, int] | None:
        """(h, w, channels) of a batch-of-one map of real or quantised values, else None."""
        shape, dtype = tensor.shape, np.dtype(tensor.dtype)
        if len(shape) != 4 or shape[0] not in (1, None) or None in shape[1:]:
            return None
        if not (np.issubdtype(dtype, np.floating) or dtype in (np.uint8, np.int8)):
            return None
        h, w, c = (shape[1], shape[2], shape[3]) if self.layout == "nhwc" else (shape[2], shape[3], shape[1])
        return (int(h), int(w), int(c)) if h > 1 and w > 1 else None  # type: ignore[operator]

    @property
    def input_size(self) -> tuple[int, int] | None:
        """(height, width) of the one image input, when fixed."""
        if len(self.inputs) != 1 or len(self.inputs[0].shape) != 4:
            return None
        shape = self.inputs[0].shape
        h, w = (shape[1], shape[2]) if self.layout == "nhwc" else (shape[2], shape[3])
        return (h, w) if h and w else None


@dataclass(frozen=True)
class Suggestion:
    features: GraphTensor | None
    scores: GraphTensor | None


def read_graph(path: str | Path) -> ModelGraph:
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    if path.suffix == ".tflite":
        return _tflite_graph(path)
    if path.suffix == ".onnx":
        return _onnx_graph(path)
    raise ModelError(f"{path}: lostx reads .tflite (LiteRT) and .onnx (onnxruntime) models, not {path.suffix or 'this'}")


def _tflite_graph(path: Path) -> ModelGraph:
    from .tflite import names_of, open_interpreter

    interpreter = open_interpreter(path, 1)
    details = {d["index"]: d for d in interpreter.get_tensor_details()}
    # A fused tensor is shown by the first of its names no other tensor has (a description may use any).
    counts: dict[str, int] = {}
    for d in details.values():
        for name in set(names_of(d["name"])):
            counts[name] = counts.get(name, 0) + 1
    shown = {i: next((n for n in d["name"].split(";") if counts[n] == 1), d["name"]) for i, d in details.items()}
    # LiteRT's only view of the operations; a delegate's nodes repeat ones already listed.
    ops = [op for op in interpreter._get_ops_details() if op["op_name"] != "DELEGATE"]
    readers: dict[int, int] = {}
    for op in ops:
        for i in op["inputs"]:
            readers[int(i)] = readers.get(int(i), 0) + 1

    activated = {int(i) for op in ops for i in op["outputs"]
                 if op["op_name"] in ACTIVATIONS or any(names_activation(n) for n in names_of(details[int(i)]["name"]))}

    def tensor(index: int) -> GraphTensor:
        d = details[index]
        return GraphTensor(shown[index], tuple(int(v) for v in d["shape"]), np.dtype(d["dtype"]).name,
                           readers.get(index, 0), index in activated)

    activations = [tensor(int(i)) for op in ops for i in op["outputs"]]
    producers = {shown[int(o)]: (op["op_name"], shown[int(op["inputs"][0])] if len(op["inputs"]) else "")
                 for op in ops for o in op["outputs"]}
    return ModelGraph(
        path, "tflite", "nhwc",
        inputs=[tensor(int(d["index"])) for d in interpreter.get_input_details()],
        outputs=[tensor(int(d["index"])) for d in interpreter.get_output_details()],
        activations=activations,
        producers=producers,
    )


def _onnx_graph(path: Path) -> ModelGraph:
    import onnx

    try:
        model = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    except Exception as exc:  # onnx reports a bad file as DecodeError, ValueError, OSError...
        raise ModelError(f"{path} is not an ONNX model ({type(exc).__name__})") from None
    graph = model.graph
    weights = {t.name for t in graph.initializer}
    readers: dict[str, int] = {}
    for node in graph.node:
        for name in node.input:
            readers[name] = readers.get(name, 0) + 1

    activated = {name for node in graph.node if node.op_type in ACTIVATIONS for name in node.output}

    def tensor(info: onnx.ValueInfoProto) -> GraphTensor:
        kind = info.type.tensor_type
        shape = tuple(d.dim_value if d.HasField("dim_value") else None for d in kind.shape.dim)
        dtype = np.dtype(onnx.helper.tensor_dtype_to_np_dtype(kind.elem_type)).name if kind.elem_type else "unknown"
        return GraphTensor(info.name, shape, dtype, readers.get(info.name, 0), info.name in activated)

    typed = {v.name: tensor(v) for v in [*graph.input, *graph.value_info, *graph.output]}
    activations = [typed.get(name, GraphTensor(name, (), "unknown", activation=name in activated))
                   for node in graph.node for name in node.output if name]
    producers = {name: (node.op_type, node.input[0] if node.input else "") for node in graph.node
                 for name in node.output}
    return ModelGraph(
        path, "onnx", "nchw",
        inputs=[typed[v.name] for v in graph.input if v.name not in weights],
        outputs=[typed[v.name] for v in graph.output],
        activations=activations,
        producers=producers,
    )


def suggest(graph: ModelGraph) -> Suggestion:
    """The tensors that look like the class scores and the deep features (see the module's docstring)."""
    maps = [(t, shape) for t in graph.activations if (shape := graph.map_shape(t)) is not None]
    by_name = {t.name: (t, shape) for t, shape in maps}
    output_names = {t.name for t in graph.outputs}
    scores = _scores(graph, maps, by_name, output_names)
    features = _features(graph, maps, output_names, scores)
    return Suggestion(features, scores)


def _scores(graph: ModelGraph, maps: list, by_name: dict, output_names: set[str]) -> GraphTensor | None:
    narrow = [(t, s) for t, s in maps if 2 <= s[2] <= MAX_CLASSES]
    if not narrow:
        return None
    exported = [(t, s) for t, s in narrow if t.name in output_names]
    tensor, shape = (exported or narrow)[-1]
    while True:
        kind, source = graph.producers.get(tensor.name, ("", ""))
        before = by_name.get(source)
        if kind not in RESIZES or before is None or before[1][2] != shape[2] or before[1][0] > shape[0]:
            return tensor
        tensor, shape = before


def _features(graph: ModelGraph, maps: list, output_names: set[str], scores: GraphTensor | None) -> GraphTensor | None:
    size = graph.input_size
    if size is None:
        return None
    coarse = [(order, t, s) for order, (t, s) in enumerate(maps)
              if (scores is None or t.name != scores.name) and s[2] >= 64 and 8 <= size[0] / s[0] <= 32]
    exported = [item for item in coarse if item[1].name in output_names]
    if exported:
        return exported[-1][1]
    if not coarse:
        return None
    order, chosen, shape = max(coarse, key=lambda item: (item[1].readers, item[2][2], item[0]))
    if chosen.activation:
        return chosen
    # A linear projection: the activation output on its grid just before it, where there is one.
    activated = [item for item in coarse if item[1].activation and item[0] < order and item[2][:2] == shape[:2]]
    return activated[-1][1] if activated else chosen


def names_activation(name: str) -> bool:
    """Whether a tensor name's last part names an activation (a converter's name for a fused one)."""
    return ACTIVATION_NAME.fullmatch(name.rsplit("/", 1)[-1]) is not None
