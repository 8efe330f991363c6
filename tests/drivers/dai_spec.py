"""A depthai pipeline that checks every call against the installed depthai, for device-less tests.

depthai 3 refuses to create device nodes (Camera, StereoDepth, NeuralNetwork)
in a pipeline without a device (``Pipeline(False)``: "Pipeline is host only,
cannot create device node"), so :func:`drivers.oak_pipeline.build_device_pipeline`
cannot be run on a real pipeline here. :class:`SpecPipeline` stands in for
``dai.Pipeline(device)``:

* ``create(cls)`` returns a :class:`SpecNode` of the real depthai class ``cls``;
* every method call and attribute read on a node, an input, an output or an
  input map is looked up on the **real** class (through its MRO) and its
  arguments are matched against the pybind11 signatures of the installed
  depthai (names, arity, keyword names, argument types); a call no overload
  accepts fails the test with the signatures;
* nodes depthai can create without a device (ImageManip, Sync, ImageAlign)
  also get a real "shadow" node in a real ``dai.Pipeline(False)``: calls with
  plain arguments are run on it too, and config objects (``initialConfig``)
  are the real ones, so their values are read back from depthai itself;
* config objects of device-only nodes (``StereoDepth.initialConfig``) are real
  ``dai.StereoDepthConfig`` objects;
* links are recorded as ``(node, output, node, input)`` for node-by-node checks.
"""

from __future__ import annotations

import datetime
import os
import re
from dataclasses import dataclass, field
from typing import Any

import depthai as dai

#: The real classes, captured at import (tests may put stand-ins on the depthai module).
REAL_DEVICE = dai.Device
REAL_PIPELINE = dai.Pipeline
_REAL = {name: getattr(dai, name) for name in dir(dai) if not name.startswith("_")}

_SIG = re.compile(r"^(?:\d+\. )?(\w+)\((.*)\) -> (.+)$")


def _split_top(text: str, sep: str) -> list[str]:
    """Split ``text`` on ``sep`` outside brackets / angle brackets."""
    out, depth, cur, i = [], 0, "", 0
    while i < len(text):
        ch = text[i]
        if ch in "[(<":
            depth += 1
        elif ch in "])>":
            depth -= 1
        if depth == 0 and text.startswith(sep, i):
            out.append(cur)
            cur, i = "", i + len(sep)
            continue
        cur += ch
        i += 1
    out.append(cur)
    return [p.strip() for p in out if p.strip()]


@dataclass
class Param:
    name: str
    type: str
    has_default: bool


@dataclass
class Overload:
    name: str
    params: list[Param]
    returns: str


def overloads(func: Any) -> list[Overload]:
    """The pybind11 overloads of ``func``, parsed from its docstring."""
    result = []
    for line in (func.__doc__ or "").splitlines():
        m = _SIG.match(line.strip())
        if not m:
            continue
        params = []
        for part in _split_top(m.group(2), ","):
            head, *default = _split_top(part, " = ")
            name, _, typ = head.partition(": ")
            params.append(Param(name.strip(), typ.strip(), bool(default)))
        result.append(Overload(m.group(1), params, m.group(3).strip()))
    return result


def _resolve(path: str) -> Any:
    first, *rest = path.split(".")[1:]
    obj: Any = _REAL[first]
    for part in rest:
        obj = getattr(obj, part)
    return obj


def matches(value: Any, typ: str) -> bool:
    """Whether pybind11 would accept ``value`` for a parameter typed ``typ``."""
    typ = typ.strip()
    if " | " in typ:
        return any(matches(value, t) for t in _split_top(typ, " | "))
    outer, _, inner = typ.partition("[")
    args = _split_top(inner[:-1], ",") if inner else []
    if outer == "Optional":
        return value is None or matches(value, args[0])
    if outer == "Union":
        return any(matches(value, t) for t in args)
    if outer == "Annotated":
        return matches(value, args[0])
    if outer in ("tuple", "typing.Tuple"):
        return (
            isinstance(value, (tuple, list))
            and len(value) == len(args)
            and all(matches(v, t) for v, t in zip(value, args))
        )
    if outer in ("list", "collections.abc.Sequence"):
        return isinstance(value, (tuple, list)) and all(matches(v, args[0]) for v in value)
    if outer in ("Callable", "collections.abc.Callable"):
        return value is None or callable(value)
    if typ == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if typ == "float":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if typ == "bool":
        return isinstance(value, bool)
    if typ == "str":
        return isinstance(value, str)
    if typ == "os.PathLike":
        return isinstance(value, (str, os.PathLike))
    if typ == "datetime.timedelta":
        return isinstance(value, datetime.timedelta)
    if typ == "object":
        return True
    if typ.startswith("depthai."):
        cls = _resolve(typ)
        if isinstance(value, _Spec):
            return issubclass(value.spec, cls)
        return isinstance(value, cls)
    raise AssertionError(f"dai_spec cannot check the pybind type {typ!r}")


def check_call(cls: type, name: str, args: tuple, kwargs: dict) -> Overload:
    """The overload of ``cls.name`` that accepts ``args`` / ``kwargs``; AssertionError if none."""
    func = _lookup(cls, name)
    assert func is not None, f"depthai {cls.__name__} has no {name!r}"
    sigs = overloads(func)
    assert sigs, f"depthai {cls.__name__}.{name} has no parsable signature: {func.__doc__!r}"
    for sig in sigs:
        params = [p for p in sig.params if p.name != "self" and not p.name.startswith("*")]
        if any(p.name.startswith("*") for p in sig.params):
            raise AssertionError(f"depthai {cls.__name__}.{name} takes *args/**kwargs; check it by hand")
        if len(args) > len(params):
            continue
        bound = dict(zip((p.name for p in params), args))
        if any(k in bound or k not in {p.name for p in params} for k in kwargs):
            continue
        bound.update(kwargs)
        if any(p.name not in bound and not p.has_default for p in params):
            continue
        if all(matches(bound[p.name], p.type) for p in params if p.name in bound):
            return sig
    shown = "; ".join(f"{s.name}({', '.join(f'{p.name}: {p.type}' for p in s.params[1:])})" for s in sigs)
    raise AssertionError(f"depthai {cls.__name__}.{name} accepts none of the arguments {args!r} {kwargs!r}: {shown}")


def _lookup(cls: type, name: str) -> Any:
    for klass in cls.__mro__:
        if name in klass.__dict__:
            return klass.__dict__[name]
    return None


def _has_spec(values: Any) -> bool:
    return any(isinstance(v, _Spec) for v in values)


class _Spec:
    spec: type
    owner: "SpecNode"


@dataclass
class Call:
    target: str
    name: str
    args: tuple
    kwargs: dict


class _Checked(_Spec):
    """Attribute access checked against ``spec``; calls recorded on the pipeline."""

    def __init__(self, spec: type, owner: "SpecNode | None", label: str, shadow: Any = None) -> None:
        self.spec = spec
        self.owner = owner if owner is not None else self  # type: ignore[assignment]
        self.label = label
        self.shadow = shadow

    def _pipeline(self) -> "SpecPipeline":
        return self.owner.pipeline  # type: ignore[union-attr]

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        member = _lookup(self.spec, name)
        assert member is not None, f"depthai {self.spec.__name__} has no attribute {name!r}"
        if isinstance(member, property):
            typ = (member.fget.__doc__ or "").strip().rpartition("-> ")[2]
            return self._property(name, typ)
        return lambda *args, **kwargs: self._call(name, args, kwargs)

    def _property(self, name: str, typ: str) -> Any:
        shadow = None if self.shadow is None else getattr(self.shadow, name)
        if typ in ("depthai.Node.Input", "depthai.Node.Output"):
            kind = SpecInput if typ.endswith("Input") else SpecOutput
            return kind(self.owner, name, shadow)
        if typ == "depthai.Node.InputMap":
            return SpecInputMap(self.owner, name, shadow)
        if shadow is not None:  # a real config object of a real host node: calls checked, recorded, run
            return _Checked(_resolve(typ), self.owner, f"{self.label}.{name}", shadow)
        return self.owner.configs.setdefault(name, _resolve(typ)())

    def _call(self, name: str, args: tuple, kwargs: dict) -> Any:
        sig = check_call(self.spec, name, args, kwargs)
        self._pipeline().calls.append(Call(self.label, name, args, kwargs))
        if self.shadow is not None and not _has_spec(args) and not _has_spec(kwargs.values()):
            result = getattr(self.shadow, name)(*args, **kwargs)
            if sig.returns in ("None", "bool") or sig.returns.startswith(
                ("depthai.MessageQueue", "depthai.InputQueue")
            ):
                return result
        if sig.returns == "None":
            return None
        if sig.returns == "bool":
            return True
        if sig.returns == "depthai.Node.Output":
            made = sum(1 for c in self._pipeline().calls if c.target == self.label and c.name == name) - 1
            return SpecOutput(self.owner, f"{name}#{made}", None)
        if sig.returns.startswith("depthai.node.") and issubclass(self.spec, _resolve(sig.returns)):
            return self
        return SpecValue(sig.returns, f"{self.label}.{name}")


@dataclass
class SpecValue:
    """What a device-only call returns (e.g. a MessageQueue of a NeuralNetwork input)."""

    type: str
    origin: str


class SpecNode(_Checked):
    def __init__(self, pipeline: "SpecPipeline", spec: type, index: int, shadow: Any) -> None:
        self.pipeline = pipeline
        self.configs: dict[str, Any] = {}
        super().__init__(spec, None, f"{spec.__name__}#{index}", shadow)
        self.owner = self


class SpecInput(_Checked):
    def __init__(self, owner: SpecNode, name: str, shadow: Any) -> None:
        super().__init__(dai.Node.Input, owner, f"{owner.label}.{name}", shadow)
        self.name = name


class SpecOutput(_Checked):
    def __init__(self, owner: SpecNode, name: str, shadow: Any) -> None:
        super().__init__(dai.Node.Output, owner, f"{owner.label}.{name}", shadow)
        self.name = name

    def link(self, target: Any) -> None:
        check_call(dai.Node.Output, "link", (target,), {})
        self.owner.pipeline.links.append((self.owner, self.name, target.owner, target.name))
        self.owner.pipeline.inputs[(target.owner.label, target.name)] = target
        if self.shadow is not None and target.shadow is not None:  # both ends real host nodes: link them
            self.shadow.link(target.shadow)


class SpecInputMap(_Checked):
    def __init__(self, owner: SpecNode, name: str, shadow: Any) -> None:
        super().__init__(dai.Node.InputMap, owner, f"{owner.label}.{name}", shadow)
        self.name = name

    def __getitem__(self, key: str) -> SpecInput:
        check_call(dai.Node.InputMap, "__getitem__", (key,), {})
        shadow = None if self.shadow is None else self.shadow[key]
        return SpecInput(self.owner, f"{self.name}[{key!r}]", shadow)


@dataclass
class SpecPipeline:
    """Stand-in for ``dai.Pipeline(device)`` (see the module docstring)."""

    nodes: list[SpecNode] = field(default_factory=list)
    links: list[tuple[SpecNode, str, SpecNode, str]] = field(default_factory=list)
    calls: list[Call] = field(default_factory=list)
    host: Any = field(default_factory=lambda: REAL_PIPELINE(False))
    feeds: dict[str, Any] = field(default_factory=dict)
    stop_error: Exception | None = None

    @property
    def host_fed(self) -> list[tuple[SpecNode, SpecInput]]:
        """Inputs of real host nodes linked from device stand-ins (nothing real feeds them)."""
        out = []
        for src, _output, dst, _name in self.links:
            if dst.shadow is not None and src.shadow is None:
                out.append((dst, self.inputs[(dst.label, _name)]))
        return out

    def __post_init__(self) -> None:
        self.inputs: dict[tuple[str, str], SpecInput] = {}

    def create(self, cls: type) -> SpecNode:
        # Pipeline.create(arg0: object, *args, **kwargs): the class must be a depthai node class
        assert isinstance(cls, type) and issubclass(cls, dai.Node), f"Pipeline.create needs a node class, got {cls!r}"
        try:
            shadow = self.host.create(cls)
        except RuntimeError as exc:
            assert "host only" in str(exc), exc
            shadow = None
        node = SpecNode(self, cls, len(self.nodes), shadow)
        self.nodes.append(node)
        return node

    def of(self, cls: type) -> list[SpecNode]:
        """Nodes of class ``cls``, in creation order."""
        return [n for n in self.nodes if n.spec is cls]

    def calls_of(self, node: SpecNode, name: str | None = None) -> list[Call]:
        """Calls made on ``node`` (and its inputs/outputs), optionally of one method."""
        return [c for c in self.calls if c.target.split(".")[0] == node.label and (name is None or c.name == name)]

    def linked(self, out_node: SpecNode, output: str, in_node: SpecNode, input_: str) -> bool:
        return (out_node, output, in_node, input_) in self.links


class SpecDevice(_Spec):
    """Stand-in for an open ``dai.Device``: calls checked against the real class, answers given.

    Parameters
    ----------
    answers : dict
        Method name -> value returned (checked against the method's return
        type); methods returning None need no answer.
    close_s : float
        How long ``close()`` takes (a device that hangs on close).
    """

    def __init__(self, answers: dict[str, Any], close_s: float = 0.0) -> None:
        self.spec = REAL_DEVICE
        self.owner = self  # type: ignore[assignment]
        self.answers = answers
        self.close_s = close_s
        self.calls: list[Call] = []

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)

        def call(*args: Any, **kwargs: Any) -> Any:
            sig = check_call(REAL_DEVICE, name, args, kwargs)
            self.calls.append(Call("Device", name, args, kwargs))
            if name == "close":
                import time

                time.sleep(self.close_s)
            if isinstance(self.answers.get(name), Exception):
                raise self.answers[name]
            if sig.returns == "None":
                return None
            assert name in self.answers, f"the test gives no answer for Device.{name}"
            value = self.answers[name]
            if isinstance(value, Exception):  # what depthai raises
                raise value
            if sig.returns != "object":
                assert matches(value, sig.returns), f"answer {value!r} for Device.{name} is not a {sig.returns}"
            return value

        return call


def _spec_pipeline_method(name: str) -> Any:
    def method(self: "SpecPipeline", *args: Any, **kwargs: Any) -> Any:
        check_call(REAL_PIPELINE, name, args, kwargs)
        self.calls.append(Call("Pipeline", name, args, kwargs))
        if name == "start":
            # host inputs of real host nodes that device stand-ins would feed: the test sends into them
            for _node, inp in self.host_fed:
                self.feeds[inp.name] = inp.shadow.createInputQueue(maxSize=8, blocking=False)
            for node in self.nodes:  # the shadows of device nodes (ImageManip, ImageAlign) idle on the host
                if node.shadow is not None and not node.shadow.runOnHost():
                    node.shadow.setRunOnHost(True)
            self.host.start()
        elif name == "stop":
            self.host.stop()
            if self.stop_error is not None:
                raise self.stop_error
        return None

    return method


SpecPipeline.start = _spec_pipeline_method("start")  # type: ignore[attr-defined]
SpecPipeline.stop = _spec_pipeline_method("stop")  # type: ignore[attr-defined]
SpecPipeline.setStopOnDeviceLoss = _spec_pipeline_method("setStopOnDeviceLoss")  # type: ignore[attr-defined]


def camera_features(
    colour_fps: float, mono_fps: float, colour_size: tuple[int, int] = (4208, 3120), binned_fps: float | None = None
) -> list:
    """Real ``dai.CameraFeatures``: colour (IMX214) + two mono (OV7251) sensors.

    One full-size mode per sensor, plus, with ``binned_fps``, a colour mode of
    half the size at that rate.
    """
    out = []
    for socket, name, size, fps in (
        (dai.CameraBoardSocket.CAM_A, "IMX214", colour_size, colour_fps),
        (dai.CameraBoardSocket.CAM_B, "OV7251", (640, 480), mono_fps),
        (dai.CameraBoardSocket.CAM_C, "OV7251", (640, 480), mono_fps),
    ):
        feature = dai.CameraFeatures()
        feature.socket, feature.sensorName = socket, name
        feature.width, feature.height = size
        modes = [(size, fps)]
        if binned_fps is not None and name == "IMX214":
            modes.append(((size[0] // 2, size[1] // 2), binned_fps))
        configs = []
        for (w, h), rate in modes:
            config = dai.CameraSensorConfig()
            config.width, config.height, config.minFps, config.maxFps = w, h, 1.0, rate
            configs.append(config)
        feature.configs = configs
        out.append(feature)
    return out
