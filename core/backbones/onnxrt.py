"""Any ONNX segmentation model, run with onnxruntime, its tensors named by a description (``--backbone onnx``).

The CUDA execution provider runs it where onnxruntime has one and a GPU is
there (``device = "auto"``, the default, or ``cuda[:N]``); the CPU otherwise.
A feature or score tensor that is not an output of the graph is made one
before the session starts (with the ``onnx`` package).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from ..config import BackboneConfig
from ..errors import InputError, ModelError
from .description import GUIDE, ModelDescription, read_description
from .runtime import DescribedBackbone, TensorSpec

DTYPES = {
    "tensor(float)": np.float32, "tensor(float16)": np.float16, "tensor(double)": np.float64,
    "tensor(uint8)": np.uint8, "tensor(int8)": np.int8,
}


def providers_for(device: str, available: list[str]) -> list[Any]:
    """onnxruntime execution providers for ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA where there is one)."""
    if device == "cpu":
        return ["CPUExecutionProvider"]
    match = re.fullmatch(r"cuda(?::(\d+))?", device)
    if device != "auto" and match is None:
        raise InputError(f"device {device!r} is not one of auto, cpu, cuda, cuda:N")
    if "CUDAExecutionProvider" not in available:
        if device == "auto":
            return ["CPUExecutionProvider"]
        raise ModelError(f"device {device!r} was asked for, but this onnxruntime has no CUDA provider "
                         f"(it has {', '.join(available)}; install onnxruntime-gpu); use --device cpu")
    index = int(match.group(1) or 0) if match else 0
    return [("CUDAExecutionProvider", {"device_id": index}), "CPUExecutionProvider"]


def model_bytes(path: Path, wanted: list[str]) -> bytes:
    """The model with each ``wanted`` tensor among the graph's outputs (intermediate ones added)."""
    import onnx

    try:
        model = onnx.load(str(path))
    except Exception as exc:  # onnx reports a bad file as DecodeError, ValueError, OSError...
        raise ModelError(f"{path} is not an ONNX model ({type(exc).__name__}); pass another with --model PATH") from None
    outputs = {o.name for o in model.graph.output}
    produced = {name for node in model.graph.node for name in node.output}
    weights = {t.name for t in model.graph.initializer}
    for name in wanted:
        if name in outputs:
            continue
        if name not in produced:
            kind = "a weight, not an activation" if name in weights else "no tensor of the graph"
            raise ModelError(f"{path}: {name!r} is {kind} ({GUIDE})")
        model.graph.output.append(onnx.ValueInfoProto(name=name))
        outputs.add(name)
    return model.SerializeToString()


class OnnxBackbone(DescribedBackbone):
    """An ONNX model described by a :class:`ModelDescription`."""

    layout = "nchw"

    def __init__(self, description: ModelDescription, config: BackboneConfig, name: str = "onnx") -> None:
        import onnxruntime as ort

        if config.threads < 1:
            raise InputError(f"threads must be at least 1, got {config.threads}")
        providers = providers_for(config.device, ort.get_available_providers())
        options = ort.SessionOptions()
        options.intra_op_num_threads = config.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only: lostx reports what matters in one line
        # Threads that spin while they wait take the cores from everything else on a busy machine: ESPNetv2
        # took 393 ms per frame spinning and 214 ms not, at a load average of 7 on 2 cores.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        wanted = [description.features, description.scores]
        try:
            self._session = ort.InferenceSession(model_bytes(description.model, wanted), options, providers=providers)
        except (RuntimeError, ValueError) as exc:  # onnxruntime's Fail / InvalidGraph derive from RuntimeError
            reason = str(exc).strip().splitlines()[0][:200]
            raise ModelError(f"{description.model}: onnxruntime cannot load it ({reason})") from None
        self._wanted = wanted
        self.providers = self._session.get_providers()
        super().__init__(description, name)

    def _input_spec(self) -> TensorSpec:
        inputs = self._session.get_inputs()
        if len(inputs) != 1:
            raise ModelError(f"{self.description.model} has {len(inputs)} inputs; lostx feeds models one image")
        node = inputs[0]
        if node.type not in DTYPES:
            raise ModelError(f"{self.description.model}: input {node.name!r} is {node.type}, not an image tensor")
        shape = tuple(v if isinstance(v, int) else None for v in node.shape)
        return TensorSpec(node.name, shape, np.dtype(DTYPES[node.type]))

    def _run(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        try:
            features, scores = self._session.run(self._wanted, {self._input.name: batch})
        except Exception as exc:  # onnxruntime raises its own Fail, InvalidArgument... on a bad run
            raise ModelError(f"{self.description.model} failed to run: {str(exc).strip().splitlines()[0][:200]}") from None
        return features, scores

    def _output_specs(self, features: np.ndarray, scores: np.ndarray) -> tuple[TensorSpec, TensorSpec]:
        return (TensorSpec(self.description.features, features.shape, features.dtype),
                TensorSpec(self.description.scores, scores.shape, scores.dtype))


def load_onnx(config: BackboneConfig, path: Path | None) -> OnnxBackbone:
    """``--backbone onnx --model FILE``: FILE is the description, or the model with its ``.toml`` beside it."""
    if path is None:
        raise ModelError("backbone 'onnx' needs its model: pass --model PATH (the .onnx file with its .toml "
                         "description beside it, or the .toml)")
    return OnnxBackbone(read_description(path), config)
