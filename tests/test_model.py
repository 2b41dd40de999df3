"""The synthetic model: architecture, determinism, and accuracy on generated scenes."""

from __future__ import annotations

import hashlib

import numpy as np
import onnx
import pytest
from monitor.models import synthetic

from monitor.scene import WORKWEAR_BGR, Figure, draw_figure, random_frames
from monitor.scene.accuracy import Accuracy, cell_tolerance_px, score_frame

# The bytes of the default build; change only together with models/README.md.
EXPECTED_SHA256 = "9b0fa13cf5ccb14834e90969fffd3f446781de9fc4aa26325148f6bcb0302ee3"


def test_build_is_deterministic_and_matches_the_model_card(tmp_path, synthetic_model):
    again = synthetic.write_model(tmp_path / "again.onnx")
    first = hashlib.sha256(synthetic_model.read_bytes()).hexdigest()
    assert first == again == EXPECTED_SHA256


def _square_only_build() -> bytes:
    """The 2026-11-28 default build, remade from today's: a fixed 416x416 input, no imgsz."""
    model = synthetic.build_model()
    g = model.graph
    for value, dims in ((g.input[0], (416, 416)), (g.output[0], (13, 13)),
                        (g.output[1], (26, 26))):
        for d, v in zip(value.type.tensor_type.shape.dim[2:], dims, strict=True):
            d.ClearField("dim_param")
            d.dim_value = v
    keep = [p for p in model.metadata_props if p.key != "imgsz"]
    del model.metadata_props[:]
    model.metadata_props.extend(keep)
    return model.SerializeToString(deterministic=True)


def test_an_earlier_default_build_in_the_cache_is_built_anew(tmp_path, monkeypatch):
    # an upgrade must run this version's model, not the square-only one left in the cache;
    # a copy of it at a path of the user's is never touched
    old = _square_only_build()
    assert synthetic.OLDER_BUILDS[len(old)] == hashlib.sha256(old).hexdigest()
    monkeypatch.setenv("WORKCELL_MONITOR_HOME", str(tmp_path / "home"))
    cached = synthetic.default_model_path()
    cached.parent.mkdir(parents=True)
    cached.write_bytes(old)
    mine = tmp_path / "mine.onnx"
    mine.write_bytes(old)
    same_size = tmp_path / "same-size.onnx"  # another file of that size: kept, not rebuilt
    same_size.write_bytes(b"x" * len(old))
    assert synthetic.is_older_build(cached) and not synthetic.is_older_build(same_size)
    assert synthetic.ensure_model() == cached
    assert hashlib.sha256(cached.read_bytes()).hexdigest() == EXPECTED_SHA256
    assert synthetic.ensure_model(mine) == mine and mine.read_bytes() == old
    cached.write_bytes(old)  # the CLI's path (with its progress line) does the same
    from monitor.cli.run import ensure_model

    assert ensure_model() == cached
    assert hashlib.sha256(cached.read_bytes()).hexdigest() == EXPECTED_SHA256


def test_graph_is_the_seeds_layer_table(synthetic_model):
    model = onnx.load(str(synthetic_model))
    params = sum(int(np.prod(t.dims)) for t in model.graph.initializer)
    assert params == 8_849_182
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    assert len(convs) == 13
    assert model.opset_import[0].version >= 13
    def dims(value_info):
        return [d.dim_param or d.dim_value for d in value_info.type.tensor_type.shape.dim]

    # a dynamic batch dimension: frames of several cameras run as one batch; dynamic height
    # and width: a 16:9 frame runs at 416x288 (the full input is the imgsz metadata)
    outs = {o.name: dims(o) for o in model.graph.output}
    assert outs == {"output_13": ["batch", 255, "height/32", "width/32"],
                    "output_26": ["batch", 255, "height/16", "width/16"]}
    assert dims(model.graph.input[0]) == ["batch", 3, "height", "width"]
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["imgsz"] == "416"


def test_one_figure_gives_one_box_around_it(detector):
    frame = np.full((720, 1280, 3), 120, np.uint8)
    draw_figure(frame, Figure((640.0, 600.0), 300.0, phase=0.7))
    persons = detector.detect(frame)
    assert len(persons) == 1
    x1, y1, x2, y2 = persons.boxes_px[0]
    assert x1 <= 640 - 0.2 * 300 and x2 >= 640 + 0.2 * 300 and y1 <= 300 and y2 >= 600
    assert persons.scores[0] > 0.9


@pytest.mark.parametrize("bgr", [(30, 30, 220), (220, 40, 30), (203, 192, 255), (235, 235, 235),
                                 (0, 140, 255), (0, 220, 255), (150, 110, 150)],
                         ids=["red", "blue", "pink", "white", "orange", "yellow", "grey-purple"])
def test_figures_in_other_colours_are_not_persons(detector, bgr):
    frame = np.full((720, 1280, 3), 120, np.uint8)
    draw_figure(frame, Figure((640.0, 600.0), 300.0, colours=(bgr,) * 4))
    assert len(detector.detect(frame)) == 0


def test_a_small_work_wear_patch_is_not_a_person(detector):
    frame = np.full((1080, 1920, 3), 120, np.uint8)
    frame[500:516, 900:916] = WORKWEAR_BGR[0]  # 16 px: far below the smallest person
    assert len(detector.detect(frame)) == 0
    frame[400:700, 900:1000] = WORKWEAR_BGR[0]  # a person-sized block of the colour is
    assert len(detector.detect(frame)) == 1


@pytest.mark.slow
def test_accuracy_on_60_generated_frames(detector):
    # the 200-frame figures are `monitor model eval` (models/README.md); 60 keep the suite short
    size = (1920, 1080)
    acc = Accuracy()
    tol = cell_tolerance_px(size)
    for image, truth in random_frames(60, seed=0, size=size):
        score_frame(detector.detect(image).boxes_px, truth, tol, acc)
    print(f"recall {acc.recall:.4f} precision {acc.precision:.4f} mean IoU {acc.mean_iou:.3f} "
          f"one box {acc.one_box_share:.4f} persons {acc.persons}")
    assert acc.persons > 90
    assert acc.recall >= 0.98
    assert acc.precision >= 0.98
    assert acc.one_box_share >= 0.98
    assert acc.distractor_hits == 0
    assert 0.5 < acc.mean_iou < 1.0


def test_progress_is_silent_when_not_on_a_terminal():
    import io

    from monitor.progress import Steps, progress

    out = io.StringIO()
    assert list(progress(range(5), desc="calibrating", stream=out)) == [0, 1, 2, 3, 4]
    steps = Steps(["fp32 model", "int8 model"], "model build", stream=out)
    steps.start("building the fp32 model")
    steps.done()
    steps.start("calibrating the int8 model")
    steps.done()
    assert out.getvalue() == ""


def test_progress_draws_a_bar_on_a_terminal():
    import io

    from monitor.progress import Steps, progress

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Terminal()
    assert list(progress(range(5), desc="calibrating", stream=out)) == [0, 1, 2, 3, 4]
    assert "calibrating" in out.getvalue()
    out = Terminal()
    steps = Steps(["fp32 model"], "model build", stream=out)
    steps.start("building the fp32 model")
    assert "model build" in out.getvalue() and "building the fp32 model" in out.getvalue()
    steps.done()


def test_int8_ranges_refuse_weights_they_do_not_fit():
    assert synthetic.int8_ranges()["conv21.out"] == (0.1, 30)
    with pytest.raises(ValueError, match="row_mass_cap"):
        synthetic.int8_ranges(synthetic.SyntheticWeights(row_mass_cap=0.8))
    with pytest.raises(ValueError, match="exceed"):
        synthetic.int8_ranges(synthetic.SyntheticWeights(mass_gain=12.0))
