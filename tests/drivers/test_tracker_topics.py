"""The tracker overlay's particle points: wire bytes built as one array equal protobuf's own messages."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

from drivers.tracker_topics import _points_wire


def test_points_wire_parses_to_the_messages_protobuf_builds():
    uv = np.random.default_rng(3).normal(0.0, 500.0, size=(257, 2))
    uv[0] = 0.0  # proto3 omits default fields: an explicit zero must parse the same
    uv[1] = (-0.0, 1e-300)
    uv[2] = (np.finfo(float).max, -np.finfo(float).tiny)
    built = PointsAnnotation(thickness=2.0)
    built.MergeFromString(_points_wire(PointsAnnotation, Point2, uv))
    reference = PointsAnnotation(thickness=2.0, points=[Point2(x=float(u), y=float(v)) for u, v in uv])
    assert built == reference
    assert built.SerializeToString() == reference.SerializeToString()
    assert np.array_equal([(p.x, p.y) for p in built.points], uv)
    # inside the overlay message, next to other annotations
    msg = ImageAnnotations()
    msg.points.append(built)
    assert ImageAnnotations.FromString(msg.SerializeToString()).points[0] == reference


def test_points_wire_of_no_points_is_empty():
    empty = PointsAnnotation()
    empty.MergeFromString(_points_wire(PointsAnnotation, Point2, np.zeros((0, 2))))
    assert len(empty.points) == 0
