"""Make ``fusion_pf/data/hand/hand_landmark_full_mixed.tflite`` and ``hand_landmark_full_int8.tflite``: MediaPipe's full hand-landmark model quantised.

``--model palm`` makes ``palm_detection_full_int8.tflite`` the same way (see "Palm detector" below).

Offline tool, not a runtime dependency: it needs ``ai-edge-quantizer`` (PyPI, Apache-2.0), which
fusion-pf itself never imports. Run it in a virtual environment of its own::

    python -m venv /tmp/qvenv
    /tmp/qvenv/bin/pip install ai-edge-quantizer==0.10.0 opencv-python-headless
    PYTHONPATH=. /tmp/qvenv/bin/python tools/quantise_hand_model.py --variant full_mixed
    PYTHONPATH=. /tmp/qvenv/bin/python tools/quantise_hand_model.py --variant full_int8
    PYTHONPATH=. /tmp/qvenv/bin/python tools/quantise_hand_model.py --model palm

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
7. ``full_mixed`` only (:data:`VARIANTS`): 21 more operators of the float model kept float (the
   input stage and first 56 x 56 block, operators 0-9; the last two 7 x 7 blocks, 46-56), and the
   activation ranges from the 99th percentile of each tensor's per-crop extremes
   (:func:`percentile_ranges`; the calibrator's moving average keeps the last few dozen crops').

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

Cost-aware selection (the ``full_mixed`` variant). Each operator's float cost measured as the CPU
time of the model with it kept float minus the all-int8 model's (0.00-0.37 ms; the 112 x 112
convolution 3 costs most), its gain as the error it removes, on 100 crops of the test photos
(seed 1, tracking jitter), of the **palm centre** (the mean of landmarks 0, 5, 9, 13, 17: what the
cue measures) rather than of all 21 landmarks: the two disagree (keeping operator 52 float lowers
the 21-landmark distance most and adds a palm-centre bias of 0.4 crop px; its model was less
accurate on the development frames than all-int8). Single operators move the palm error by a few
hundredths of a pixel either way (0.47 px all-int8), and greedy gain-per-ms sets do not add up
(1-8 operators: 0.39-0.42 px). Whole stages do: the input stage kept float removes a quarter of
it, the last blocks float most of the rest. Activation ranges (all-int8, 21-landmark distance): moving average 0.81,
the mean of the per-crop extremes 0.78, their 99th / 95th percentile 0.77 / 0.77, global 0.81 px
(the 99th kept: the smallest p95); 200 more calibration crops cut from square windows around the
hands (replicated or constant border, as in the development crops): 0.02 px closer on such
crops, not more accurate on the development frames (10.84 / 6.24 px all-int8). Measured
(CPU ms per call interleaved in one run, float 4.58, all-int8 1.86; palm-centre error on the
test photos' crops / on the same crops downscaled so the hand is 110-260 px, float reference;
fused RMSE on the development canvas / crops with ``recentre`` 0.18, float 10.37 / 5.92 px):

=================================  =======  ===========  =========
float besides the heads            ms/call  palm error   RMSE canvas/crops
=================================  =======  ===========  ================
none (``full_int8``)               1.86     0.47 / 0.44  10.79 / 6.18
1 (best gain per ms)               1.93     0.41 / 0.42  10.59 / 6.17
1, 10, 26, 40, 51                  2.17     0.39 / 0.41  10.76 / 6.09
0-2                                2.02     0.42 / 0.43  10.25 / 6.06
0-5                                2.10     0.37 / 0.33  10.45 / 6.03
0-9                                2.25     0.35 / 0.32  10.36 / 6.04
0-5, 46-56                         2.56     0.15 / 0.15  10.37 / 5.98
0-9, 46-56 (``full_mixed``)        2.77     0.12 / 0.12  10.48 / 5.92
0-5, 35-56                         3.25     0.11 / 0.11  10.43 / 5.94
=================================  =======  ===========  ================

The development RMSE moves by about 0.1-0.2 px with the tracked ROIs' path (a landmark
difference of a tenth of a pixel changes later ROIs); with ``recentre`` 0.14 ``full_mixed`` gives
10.20 / 5.92 px (float 10.04 / 5.92 at 0.14 in ``benchmarks/peer.py``'s run; 0.1: float 10.03 /
5.96, ``full_mixed`` 10.08 / 5.97). Tracking frames against MediaPipe (``benchmarks/peer.py``,
CPU ratio median / p95, quiet and one core busy, load 6-15 on 2 CPUs): ``full_mixed`` with
``recentre`` 0.18 (a second call on 4 of 105 frames) 0.84x / 0.85x quiet, 0.71x / 0.78x busy,
canvas 10.48 px; with 0.17 (6 frames) 0.75-0.77x / 1.07-1.12x quiet, 0.75x / 0.99-1.13x busy,
10.24 px; with 0.16 (8 frames) 0.77x / 1.18x quiet, 0.75x / 1.28x busy, 10.14 px. A frame with
a second call costs two model calls and two warps (about 6.5-7 ms CPU, MediaPipe's p95 6-7 ms):
the p95 line holds only while fewer than 1 frame in 20 re-centres, and the canvas accuracy
only with more. Shifting the landmark ROI by the filter's predicted displacement halves the
second calls but costs accuracy (0.18: 10.84 / 5.99 px; 0.14: 10.35 / 6.07). The second call on
``full_int8`` (0.17: 10.17 / 5.92 px) still leaves the p95 at 1.07-1.22x (two runs each): a
single-call frame costs 4.5 ms CPU at the median, so any second call passes MediaPipe's p95.
=======
Palm detector (``--model palm``; issue 25, acquisition frames). Steps 1, 2, 5 and 6 as above;
step 3 is :func:`palm_calibration_frames` (240 whole frames letterboxed to 192 x 192 as the hand
cue does, the test photos pasted at 0.3-1.2 x the frame height, a quarter without a hand); step 4
keeps :data:`PALM_FLOAT` float. The quantiser has no int8 PReLU: the model's 31 PReLUs stay float
between a dequantise and a quantise. Measured (the float detector as reference: recall and
keypoint distance over 22 images, MediaPipe's test photos, mirrored, and pasted into 1280 x 720
canvases at 0.3 / 0.5 / 0.8 x the height with another seed; CPU ms per call against the float
model's 5.1-5.3 in the same run; fused RMSE / median / p95 on the development canvas, float
10.4 / 8.8 / 16.7 px):

=====================================  =======  ======  ===========  ==================
float besides the heads                ms/call  recall  keypoint px  canvas RMSE/med/p95
=====================================  =======  ======  ===========  ==================
nothing                                3.72     0.91    9.5          10.2 / 8.5 / 16.7,
                                                                     coverage 99.1 %
the upsampling path (24 x 24, 12 x 12)  4.11     0.91    8.1
the first 96 x 96 block (kept)         4.05     1.00    6.2          10.4 / 8.8 / 17.3
both                                                                 10.4 / 8.7 / 16.8,
                                                                     crops 6.0 / 4.7 / 10.6
kept, 480 frames, seed 1                                             10.4 / 8.8 / 17.3,
                                                                     crops 5.9 / 4.8 / 10.4
MediaPipe's lite detector (reference)  --       0.86    14.2
=====================================  =======  ======  ===========  ==================

With nothing else float, the canvas's first frame had no palm (coverage 99.1 %) and a hand of
``hands.jpg`` at half size was lost. The kept model finds every palm the float model finds (3
more, weaker, detections) but the canvas p95 is 0.6 px worse (crops 5.9 / 4.8 / 10.2 against
5.9 / 4.7 / 10.3), with twice the calibration frames too: not the default. Its first lock
on the canvas is its first frame, as the float model's. Not faster: the PReLUs rewritten to int8
after quantisation (per-tensor int8 slopes, the dequantise / quantise around them dropped) run
outside XNNPACK in ai-edge-litert 2.3 (10.8 ms per call).

``benchmarks/peer.py`` on the development canvas (acquisition frames: palm detection and one
landmark call each side), CPU time ratios fusion-pf / MediaPipe, median / p95 / p99, quiet and one
core busy: float detector 0.90 / 0.90 / 0.89x and 0.92 / 0.92 / 0.94x, this one 0.79 / 0.91 /
0.90x and 0.82 / 0.84 / 0.85x (load average 2.1-2.4 on 2 CPUs; fusion-pf's wall p99 12-16 ms);
in an earlier run at load 9-14 0.93 / 0.89 / 0.95x, 0.95 / 0.86 / 0.87x against 0.85 / 0.88 /
0.90x, 0.84 / 0.93 / 0.91x (wall times there are no measure: p99 25-58 ms, MediaPipe's 31-76).
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

    landmarker = HandLandmarker(landmark_model="full")  # the float model finds the hands, whatever the default
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


#: Operators the landmark model keeps float (step 4): its fully-connected heads and their sigmoids.
LANDMARK_FLOAT = tuple((".*", op) for op in ("FULLY_CONNECTED", "LOGISTIC"))
#: Operators the palm detector keeps float: its first block at 96 x 96 (the stem convolution and
#: four residual units: convolutions, depthwise convolutions, additions), its four SSD head
#: convolutions (``classifier_palm_*``, ``regressor_palm_*``) and what reshapes and concatenates
#: them into the outputs. (Its PReLUs stay float too: the quantiser has no int8 PReLU.)
PALM_FLOAT = (
    (".*(batch_normalization(_[1-4])?/|depthwise_conv2d(_[0-3])?/|add(_[0-3])?/).*", "*"),
    (".*(classifier|regressor)_palm.*", "*"),
    ("Identity.*", "*"),
)


def palm_calibration_frames(n: int = 240, seed: int = 0) -> np.ndarray:
    """Float palm-detector inputs ``(n, 1, 192, 192, 3)`` in [0, 1]: frames letterboxed as
    :meth:`HandLandmarker.palms` does (palm mode, step 3).

    Each frame is 1280 x 720 or 640 x 480 (the cameras' sizes) holding one of the test photos
    (mirrored half of the time), scaled 0.3-1.2 x the frame height, rotated up to 0.4 rad and
    placed anywhere, on a grey, noisy or the hand-free ``dino_720.jpg`` background, with contrast
    and brightness jitter; every fourth frame has no hand photo (the hand-free background alone),
    so the score head's range covers "no palm" too."""
    import cv2

    from fusion_pf.cues.hand import PALM_INPUT, HandRoi

    rng = np.random.default_rng(seed)
    read = lambda p: cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB)
    hands = [read(p) for p in sorted(PHOTOS.glob("*.jpg")) if p.name != "dino_720.jpg"]
    dino = read(PHOTOS / "dino_720.jpg")
    out = []
    for k in range(n):
        w, h = ((1280, 720), (640, 480))[int(rng.integers(2))]
        kind = int(rng.integers(3))
        if kind == 0:
            frame = np.full((h, w, 3), rng.integers(0, 256, 3), np.uint8)
        elif kind == 1:
            frame = rng.integers(0, 256, (h // 8, w // 8, 3)).astype(np.uint8)
            frame = cv2.resize(frame, (w, h), interpolation=cv2.INTER_LINEAR)
        else:
            frame = cv2.resize(dino, (w, h), interpolation=cv2.INTER_LINEAR)
        if k % 4:
            photo = hands[int(rng.integers(len(hands)))]
            photo = np.ascontiguousarray(photo[:, ::-1]) if rng.random() < 0.5 else photo
            ph, pw = photo.shape[:2]
            s = h * rng.uniform(0.3, 1.2) / ph
            m = cv2.getRotationMatrix2D((pw / 2, ph / 2), float(np.degrees(rng.normal(0, 0.2))), s)
            m[:, 2] += (rng.uniform(0, w) - pw / 2, rng.uniform(0, h) - ph / 2)
            mask = cv2.warpAffine(np.full((ph, pw), 255, np.uint8), m, (w, h))
            pasted = cv2.warpAffine(photo, m, (w, h))
            frame = np.where(mask[..., None] > 127, pasted, frame)
        roi = HandRoi((w - 1) / 2, (h - 1) / 2, float(max(w, h)))
        c = roi.sample(frame, PALM_INPUT, zero_border=True).astype(np.float32)
        c = np.clip((c - 128) * rng.uniform(0.7, 1.3) + 128 + rng.normal(0, 25), 0, 255)
        out.append((c / 255).astype(np.float32)[None])
    return np.stack(out)


def quantise(
    model_bytes: bytes,
    crops: np.ndarray,
    keep_float: tuple[tuple[str, str], ...] = LANDMARK_FLOAT,
    float_ops: tuple[int, ...] = (),
    percentile: float | None = None,
) -> bytes:
    """Static int8 with the ``keep_float`` operators (scope regex, operation) float (step 4); ``float_ops``: the
    indices of further operators of the float model kept float (step 7); ``percentile``: activation ranges from
    :func:`percentile_ranges` instead of the calibrator's moving average."""
    import re

    from ai_edge_litert.interpreter import Interpreter
    from ai_edge_quantizer import quantizer, recipe

    heads_float = [{"regex": rx, "operation": op, "algorithm_key": "no_quantize"} for rx, op in keep_float]
    graph = _read(model_bytes).subgraphs[0]
    # an operator's scope is its output tensors' names joined by ";": the first one names it
    kept_float = [
        {
            "regex": re.escape(graph.tensors[graph.operators[i].outputs[0]].name.decode()) + "(;|$)",
            "operation": "*",
            "algorithm_key": "no_quantize",
        }
        for i in float_ops
    ]
    q = quantizer.Quantizer(bytearray(model_bytes), recipe.static_wi8_ai8() + heads_float + kept_float)
    name = Interpreter(model_content=model_bytes).get_input_details()[0]["name"]
    result = q.calibrate({"serving_default": [{name: c} for c in crops]})
    if percentile is not None:
        result = percentile_ranges(model_bytes, crops, result, percentile)
    return bytes(q.quantize(result).quantized_model)


def _read(model_bytes: bytes):
    from ai_edge_litert.tools import flatbuffer_utils

    return flatbuffer_utils.read_model_from_bytearray(bytearray(model_bytes))


def percentile_ranges(model_bytes: bytes, crops: np.ndarray, result: dict, p: float) -> dict:
    """``result`` (the calibrator's ranges) with every activation's range replaced by the ``p``-th percentile
    of its per-crop maxima and the ``100 - p``-th of its per-crop minima (step 7).

    The calibrator's moving average (weight 0.95 on the old value) keeps the ranges of the last few
    dozen crops; the percentiles weigh every crop the same and drop the rarest extremes.
    """
    from ai_edge_litert.interpreter import Interpreter

    it = Interpreter(model_content=model_bytes, num_threads=1, experimental_preserve_all_tensors=True)
    it.allocate_tensors()
    image = it.get_input_details()[0]["index"]
    tensors = [d for d in it.get_tensor_details() if d["dtype"] == np.float32 and d["name"] in result]
    lows: dict[str, list[float]] = {d["name"]: [] for d in tensors}
    highs: dict[str, list[float]] = {d["name"]: [] for d in tensors}
    for crop in crops:
        it.set_tensor(image, crop)
        it.invoke()
        for d in tensors:
            try:
                a = it.get_tensor(d["index"])
            except ValueError:  # a tensor the runtime does not keep
                continue
            if a.size:
                lows[d["name"]].append(float(a.min()))
                highs[d["name"]].append(float(a.max()))
    out = dict(result)
    for name, lo in lows.items():
        if lo:
            r = result[name]
            out[name] = {
                "min": np.full_like(r["min"], np.percentile(lo, 100 - p)),
                "max": np.full_like(r["max"], np.percentile(highs[name], p)),
            }
    return out


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


#: The landmark variants this tool makes: file suffix -> (float operators kept float besides the heads,
#: activation-range percentile or None for the calibrator's moving average).
VARIANTS = {
    "full_int8": ((), None),
    # the input stage (112 x 112: ops 0-3) and the first 56 x 56 block through its residual add (4-9), the
    # last two 7 x 7 blocks after add_6 through the global average pooling (46-56)
    "full_mixed": ((*range(0, 10), *range(46, 57)), 99.0),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", choices=("landmark", "palm"), default="landmark", help="which full model to quantise")
    ap.add_argument(
        "--variant", choices=tuple(VARIANTS), default="full_mixed", help="--model landmark: the landmark model to make"
    )
    ap.add_argument("--src", type=Path, help="default: the shipped full model")
    ap.add_argument(
        "--out", type=Path, help="default: hand_landmark_<variant>.tflite or palm_detection_full_int8.tflite"
    )
    args = ap.parse_args(argv)
    from ai_edge_litert.tools import flatbuffer_utils

    stem = "hand_landmark" if args.model == "landmark" else "palm_detection"
    src = args.src or HAND / f"{stem}_full.tflite"
    fp32 = bytes(flatbuffer_utils.convert_object_to_bytearray(float32_with_signature(src)))
    if args.model == "palm":
        out = args.out or HAND / f"{stem}_full_int8.tflite"
        finish(quantise(fp32, palm_calibration_frames(), PALM_FLOAT), out)
    else:
        out = args.out or HAND / f"{stem}_{args.variant}.tflite"
        float_ops, percentile = VARIANTS[args.variant]
        finish(quantise(fp32, calibration_crops(), LANDMARK_FLOAT, float_ops, percentile), out)
    print(f"wrote {out} ({out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
