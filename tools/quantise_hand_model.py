"""Make ``fusion_pf/data/hand/hand_landmark_full_int8.tflite``: MediaPipe's full hand-landmark model in int8.

Offline tool, not a runtime dependency: it needs ``ai-edge-quantizer`` (PyPI, Apache-2.0), which
fusion-pf itself never imports. Run it in a virtual environment of its own::

    python -m venv /tmp/qvenv
    /tmp/qvenv/bin/pip install ai-edge-quantizer==0.10.0 opencv-python-headless
    PYTHONPATH=. /tmp/qvenv/bin/python tools/quantise_hand_model.py

Steps (each needed by the next):

1. **fp32 weights.** The shipped ``hand_landmark_full.tflite`` stores its weights as float16
   behind ``DEQUANTIZE`` ops; the quantiser only quantises float32 constants, so every such op is
   folded (its float16 constant becomes the float32 constant the op produced).
2. **A signature** ``serving_default`` (the model has none; the calibrator needs one).
3. **Calibration crops.** 400 hand crops of 224 x 224 from the real photos of MediaPipe's own
   tests in ``tests/cues/data/hand`` (never the development frames the accuracy is measured on):
   each hand's ROI as the landmarker tracks it (also mirrored), jittered in position (10 % of the
   side), size (0.7-1.6 x), rotation (0.5 rad) and contrast / brightness; and 200 crops anywhere
   in the same photos (mostly no hand: calibrated on hands alone, the presence head read every
   crop as a hand, and a synthetic scene's fused palm went 285 px astray); seed 0.
4. **Static int8** (``recipe.static_wi8_ai8``: int8 per-channel weights, int8 activations) with
   the four fully-connected heads and their sigmoids kept float, and every output left float
   (the quantiser re-quantises them; an int8 landmark output has steps of 0.8 crop px, 2 frame
   px for a 600 px hand ROI).
5. **Input normalisation** exactly MediaPipe's: input scale 1/255, zero point -128, so the
   int8 input is ``u8 - 128`` (the calibration's average range is slightly narrower).
6. **No unused tensors or buffers.** Left in the file: step 1's float16 weights, the float32
   weights the quantiser replaced and the int8 outputs step 4 bypasses; dropped (9.2 MB to 3.7 MB,
   outputs bit-identical).

Measured (ai-edge-litert 2.3.0, XNNPACK, one thread, AMD EPYC with AVX-512 VNNI): 1.85 ms CPU per
call against 4.6 ms for the float model. Keeping the last blocks float as well (conv2d_24-30)
brought the fused RMSE on the development canvas from 10.8 to 10.6 px at 2.6 ms: not kept. Dynamic-range int8 (int8 weights, float activations)
runs outside XNNPACK in this runtime and costs 12-14 ms; weight-only int8 or fp16 weights are
dequantised at load (4.6 ms, no gain); int16 activations run outside XNNPACK (151 ms).

Selective mixed precision (measured, not kept; issue 25). Per-operator sensitivity: the model
quantised as above but with one of its 57 int8 operators kept float (a ``no_quantize`` recipe
entry on the operator's scope, the output tensor names followed by ``;``), on 120 hand crops of
the same photos drawn with another seed (tracking-like jitter: 5 % position, 0.9-1.2 x size,
0.2 rad), as the mean 2-D landmark distance to the float model in 224 px crop pixels. The error
is spread over the network: all-int8 0.80 px, the best single float operator (a convolution of the
last block, 53rd of the 57) 0.72 px, every other 0.76-0.80 px. Keeping the k most sensitive float
(CPU ms per call, single thread, against the float model's 4.8-4.9 ms in the same run; fused
RMSE on the development canvas / crops, float model 10.37 / 5.92 px):

====  =========  ========  ================
k     ms/call    distance  RMSE canvas/crops
====  =========  ========  ================
0     2.05       0.80      10.79 / 6.18
4     2.45       0.60      10.53 / 6.17
10    2.80       0.58      10.39 / 6.18
15    3.00       0.58      10.30 / 6.17
20    3.78       0.50      10.18 / 5.87
32    3.93       0.28
45    4.40       0.19
====  =========  ========  ================

The last 16 operators float: 2.89 ms, 0.60 px; k = 20 without its five high-resolution
operators: 3.34 ms, 0.66 px. Only k = 20 keeps the development accuracy, and its tracking frames
cost 0.85x / 0.84x MediaPipe's CPU median (quiet / one core busy) and 0.94x / 1.05x its p95
(``benchmarks/peer.py``, load 23-24 on 2 CPUs): short of issue 25's 0.8x and 1.0x.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
HAND = ROOT / "fusion_pf" / "data" / "hand"
PHOTOS = ROOT / "tests" / "cues" / "data" / "hand"


def float32_with_signature(src: Path):
    """The model with its float16 weights folded to float32 and a ``serving_default`` signature."""
    from ai_edge_litert import schema_py_generated as schema
    from ai_edge_litert.tools import flatbuffer_utils

    model = flatbuffer_utils.read_model(str(src))
    graph = model.subgraphs[0]
    kept = []
    for op in graph.operators:
        code = model.operatorCodes[op.opcodeIndex]
        if max(code.builtinCode, code.deprecatedBuiltinCode) == schema.BuiltinOperator.DEQUANTIZE:
            t_in, t_out = graph.tensors[op.inputs[0]], graph.tensors[op.outputs[0]]
            data = model.buffers[t_in.buffer].data
            if t_in.type == schema.TensorType.FLOAT16 and data is not None and len(data):
                weights = np.frombuffer(np.asarray(data, np.uint8).tobytes(), np.float16).astype(np.float32)
                buffer = schema.BufferT()
                buffer.data = np.frombuffer(weights.tobytes(), np.uint8)
                model.buffers.append(buffer)
                t_out.buffer = len(model.buffers) - 1
                continue
        kept.append(op)
    graph.operators = kept
    model.signatureDefs = [_signature(schema, graph)]
    return model


def _signature(schema, graph):
    sig = schema.SignatureDefT()
    sig.signatureKey, sig.subgraphIndex = "serving_default", 0

    def entry(i: int):
        t = schema.TensorMapT()
        t.name, t.tensorIndex = graph.tensors[i].name, int(i)
        return t

    sig.inputs = [entry(i) for i in graph.inputs]
    sig.outputs = [entry(i) for i in graph.outputs]
    return sig


def calibration_crops(n_per_hand: int = 40, seed: int = 0) -> np.ndarray:
    """Float crops ``(n, 1, 224, 224, 3)`` in [0, 1] around the test photos' hands (step 3)."""
    import cv2

    from fusion_pf.cues.hand import LANDMARK_INPUT, HandLandmarker, HandRoi, landmarks_roi

    landmarker = HandLandmarker()
    rng = np.random.default_rng(seed)
    rois = []
    for path in sorted(PHOTOS.glob("*.jpg")):
        photo = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        for rgb in (photo, np.ascontiguousarray(photo[:, ::-1])):
            h, w = rgb.shape[:2]
            for obs in landmarker.detect(rgb):
                r = landmarks_roi(obs.landmarks)
                for _ in range(n_per_hand):
                    u, v = r.u + rng.normal(0, 0.1) * r.size, r.v + rng.normal(0, 0.1) * r.size
                    rois.append((rgb, u, v, r.size * rng.uniform(0.7, 1.6), r.rotation + rng.normal(0, 0.5)))
            # no hand: anywhere in the photo (mostly background, some cut hands), so the presence head's
            # range covers "no hand" too (hands only: every crop reads as a hand)
            for _ in range(n_per_hand // 2):
                side = min(h, w) * rng.uniform(0.2, 0.8)
                rois.append((rgb, rng.uniform(0, w), rng.uniform(0, h), side, rng.uniform(-np.pi, np.pi)))
    crops = []
    for rgb, u, v, size, rotation in rois:
        c = HandRoi(u, v, size, rotation).sample(rgb, LANDMARK_INPUT, zero_border=False).astype(np.float32)
        c = np.clip((c - 128) * rng.uniform(0.7, 1.3) + 128 + rng.normal(0, 25), 0, 255)
        crops.append((c / 255).astype(np.float32)[None])
    return np.stack(crops)


def quantise(model_bytes: bytes, crops: np.ndarray) -> bytes:
    """Static int8 with float fully-connected heads (step 4)."""
    from ai_edge_quantizer import quantizer, recipe

    heads_float = [
        {"regex": ".*", "operation": op, "algorithm_key": "no_quantize"} for op in ("FULLY_CONNECTED", "LOGISTIC")
    ]
    q = quantizer.Quantizer(bytearray(model_bytes), recipe.static_wi8_ai8() + heads_float)
    from ai_edge_litert.interpreter import Interpreter

    name = Interpreter(model_content=model_bytes).get_input_details()[0]["name"]
    result = q.calibrate({"serving_default": [{name: c} for c in crops]})
    return bytes(q.quantize(result).quantized_model)


def finish(model_bytes: bytes, out: Path) -> None:
    """Float landmark outputs and MediaPipe's input normalisation (step 4's outputs, step 5)."""
    from ai_edge_litert import schema_py_generated as schema
    from ai_edge_litert.tools import flatbuffer_utils

    model = flatbuffer_utils.read_model_from_bytearray(bytearray(model_bytes))
    graph = model.subgraphs[0]
    outputs = [int(i) for i in graph.outputs]
    kept = []
    for op in graph.operators:
        code = model.operatorCodes[op.opcodeIndex]
        is_quantize = max(code.builtinCode, code.deprecatedBuiltinCode) == schema.BuiltinOperator.QUANTIZE
        if is_quantize and op.outputs[0] in outputs and graph.tensors[op.inputs[0]].type == schema.TensorType.FLOAT32:
            outputs[outputs.index(op.outputs[0])] = int(op.inputs[0])
            continue
        kept.append(op)
    graph.operators = kept
    graph.outputs = np.array(outputs, np.int32)
    model.signatureDefs = [_signature(schema, graph)]
    q = graph.tensors[graph.inputs[0]].quantization
    q.scale, q.zeroPoint = np.array([1 / 255], np.float32), np.array([-128], np.int64)
    drop_unused(model)
    flatbuffer_utils.write_model(model, str(out))


def drop_unused(model) -> None:
    """Drop the tensors no operator or graph input/output uses and the buffers no tensor or metadata uses (step 6).

    Order is kept, indices are renumbered. ``metadataBuffer`` (deprecated) is dropped: in the source
    model its indices already point past the buffers.
    """
    used_buffers = {0} | {int(m.buffer) for m in model.metadata or []}
    for g, graph in enumerate(model.subgraphs):
        used = {int(i) for i in (*graph.inputs, *graph.outputs)}
        for op in graph.operators:
            used |= {int(i) for i in (*op.inputs, *op.outputs, *(op.intermediates or [])) if i >= 0}
        tensor_index = {old: new for new, old in enumerate(sorted(used))}
        graph.tensors = [graph.tensors[i] for i in sorted(used)]
        graph.inputs = np.array([tensor_index[int(i)] for i in graph.inputs], np.int32)
        graph.outputs = np.array([tensor_index[int(i)] for i in graph.outputs], np.int32)
        for op in graph.operators:
            op.inputs = [tensor_index[int(i)] if i >= 0 else -1 for i in op.inputs]
            op.outputs = [tensor_index[int(i)] if i >= 0 else -1 for i in op.outputs]
            if op.intermediates is not None:
                op.intermediates = [tensor_index[int(i)] for i in op.intermediates]
        for sig in model.signatureDefs or []:
            if sig.subgraphIndex == g:
                for entry in (*sig.inputs, *sig.outputs):
                    entry.tensorIndex = tensor_index[int(entry.tensorIndex)]
        used_buffers |= {int(t.buffer) for t in graph.tensors}
    buffer_index = {old: new for new, old in enumerate(sorted(used_buffers))}
    model.buffers = [model.buffers[i] for i in sorted(used_buffers)]
    for graph in model.subgraphs:
        for t in graph.tensors:
            t.buffer = buffer_index[int(t.buffer)]
    for m in model.metadata or []:
        m.buffer = buffer_index[int(m.buffer)]
    model.metadataBuffer = None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--src", type=Path, default=HAND / "hand_landmark_full.tflite")
    ap.add_argument("--out", type=Path, default=HAND / "hand_landmark_full_int8.tflite")
    args = ap.parse_args(argv)
    from ai_edge_litert.tools import flatbuffer_utils

    fp32 = flatbuffer_utils.convert_object_to_bytearray(float32_with_signature(args.src))
    finish(quantise(bytes(fp32), calibration_crops()), args.out)
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
