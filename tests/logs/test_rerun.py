"""run.rrd read back with rerun.chunk.RrdReader and checked with the bundled `rerun` CLI."""

from __future__ import annotations

import subprocess

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from rodctl.logs.rerun import RerunSink
from rodctl.logs.synthetic import SyntheticRun

ENTITIES = {
    "/world/rod",
    "/world/target",
    "/world/gripper",
    "/world/clamp",
    "/camera/image",
    "/camera/centerline",
    "/camera/projected_truth",
    "/camera/target",
    "/control/T1",
    "/control/pixel_error",
    "/control/u/x",
    "/control/u/y",
    "/control/u/theta",
    "/control/probing/T1",
    "/control/probing/pixel_error",
    "/log",
}


def _chunks(path):
    out: dict[str, list] = {}
    for ch in RrdReader(path).stream():
        out.setdefault(ch.entity_path, []).append(ch)
    return out


def _column(chunks, name):
    """(steps, values) of one component over the non-static chunks of an entity."""
    steps, values = [], []
    for ch in chunks:
        if ch.is_static:
            continue
        rb = ch.to_record_batch()
        steps += rb.column("step").to_pylist()
        values += rb.column(name).to_pylist()
    order = np.argsort(steps, kind="stable")
    return [steps[i] for i in order], [values[i] for i in order]


def test_rrd_verify_passes(rrd_file, rerun_exe):
    res = subprocess.run(
        [rerun_exe, "rrd", "verify", str(rrd_file)], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_recording_entities_timelines_and_blueprint(rrd_file, synthetic):
    header, records = synthetic
    reader = RrdReader(rrd_file)
    [rec] = reader.recordings()
    assert rec.recording_id == header.run_id and rec.application_id == "rodctl"
    # The layout sent at the start (bounds from the rod's reach) and the one sent at close
    # (bounds around the whole run).
    assert len(reader.blueprints()) == 2
    chunks = _chunks(rrd_file)
    assert ENTITIES <= set(chunks)
    for entity in ("/world/rod", "/camera/centerline", "/control/T1", "/control/u/theta"):
        for ch in chunks[entity]:
            if not ch.is_static:
                # No wall-clock timeline: only the two simulation timelines.
                assert set(ch.timeline_names) == {"step", "sim_time"}, entity
    for entity in ("/world/target", "/world/clamp", "/camera/target"):
        assert all(ch.is_static for ch in chunks[entity]), entity


def test_logged_values(rrd_file, synthetic):
    header, records = synthetic
    chunks = _chunks(rrd_file)
    steps, t1 = _column(chunks["/control/T1"], "Scalars:scalars")
    assert steps == [r.step for r in records]
    assert [v[0] for v in t1] == [r.T1 for r in records]
    _, ux = _column(chunks["/control/u/theta"], "Scalars:scalars")
    assert [v[0] for v in ux] == [r.u[2] for r in records]
    # The world is y-up, Rerun's 2D views y-down: the rod is stored as (x, -y), float32.
    _, rod = _column(chunks["/world/rod"], "LineStrips2D:strips")
    last = np.asarray(rod[-1][0], dtype=np.float64)
    want = records[-1].centerline * [1.0, -1.0]
    assert last.shape == (51, 2) and np.allclose(last, want, atol=1e-6)
    _, px = _column(chunks["/camera/centerline"], "LineStrips2D:strips")
    assert np.allclose(np.asarray(px[3][0]), records[3].extracted, atol=1e-4)
    sim = []
    for ch in chunks["/control/T1"]:
        if not ch.is_static:
            col = ch.to_record_batch().column("sim_time")
            sim += col.cast(pa.int64()).to_pylist()
    assert sorted(sim) == [round(r.sim_time * 1e9) for r in records]
    img_steps, _ = _column(chunks["/camera/image"], "EncodedImage:blob")
    assert img_steps == [r.step for r in records if r.image is not None]


def test_two_recordings_of_the_same_records_compare_equal(tmp_path, synthetic, helpers):
    header, records = synthetic
    a = helpers.write_run(RerunSink, tmp_path / "a.rrd", header, records[:12], None)
    b = helpers.write_run(RerunSink, tmp_path / "b.rrd", header, records[:12], None)
    other = SyntheticRun(seed=4, image_every=5)
    c = helpers.write_run(RerunSink, tmp_path / "c.rrd", header, other.records(12), None)

    assert helpers.rrd_compare(a, b) == 0
    assert helpers.rrd_compare(a, c) != 0


def test_close_is_idempotent_and_write_after_close_fails(tmp_path, synthetic):
    header, records = synthetic
    sink = RerunSink(tmp_path / "x.rrd")
    sink.close(None, "failed")  # never opened: nothing to do
    assert not (tmp_path / "x.rrd").exists()
    sink = RerunSink(tmp_path / "y.rrd")
    sink.open(header)
    sink.write(records[0])
    sink.close(None, "interrupted")
    sink.close(None, "interrupted")
    with pytest.raises(RuntimeError):
        sink.write(records[1])
    chunks = _chunks(tmp_path / "y.rrd")
    steps, _ = _column(chunks["/control/T1"], "Scalars:scalars")
    assert steps == [0]  # the buffered step was sent on close


def _view_bounds(path) -> list[dict[str, dict]]:
    """Per blueprint: view name -> VisualBounds2D range."""
    reader = RrdReader(path)
    out = []
    for store in reader.blueprints():
        names, ranges = {}, {}
        for ch in reader.stream(store=store):
            rb = ch.to_record_batch()
            if "ViewBlueprint:display_name" in rb.schema.names:
                names[ch.entity_path] = rb.column("ViewBlueprint:display_name").to_pylist()[0][0]
            if "VisualBounds2D:range" in rb.schema.names:
                view = ch.entity_path.rsplit("/", 1)[0]
                ranges[view] = rb.column("VisualBounds2D:range").to_pylist()[0][0]
        out.append({names[v]: r for v, r in ranges.items()})
    return out


def test_blueprint_bounds_are_fixed_and_cover_the_whole_run(rrd_file, synthetic):
    header, records = synthetic
    blueprints = _view_bounds(rrd_file)
    scene = [b["scene (world m, y up)"] for b in blueprints]
    camera = [v for b in blueprints for k, v in b.items() if k.startswith("camera")]
    w, h = header.image_size
    for c in camera:  # the image frame, not the data: the view never refits
        assert c["x_range"][0] < 0 < w < c["x_range"][1]
        assert c["y_range"][0] < 0 < h < c["y_range"][1]
    # Stored scene points: the world with y negated.
    pts = np.concatenate([r.centerline for r in records] + [header.target_centerline]) * [1, -1]
    reach = 1.12 * header.rod_length
    start = next(b for b in scene if b["x_range"][1] - b["x_range"][0] > 2 * reach)
    final = next(b for b in scene if b is not start)
    for b in (start, final):  # both cover everything the run drew
        assert b["x_range"][0] < pts[:, 0].min() and pts[:, 0].max() < b["x_range"][1]
        assert b["y_range"][0] < pts[:, 1].min() and pts[:, 1].max() < b["y_range"][1]
    # The final box is the run's own (10 % margin), much tighter than the reach box.
    span = final["x_range"][1] - final["x_range"][0]
    assert span < 0.7 * (start["x_range"][1] - start["x_range"][0])
    assert final["x_range"][0] > pts[:, 0].min() - 0.2 * span


def test_probing_steps_are_marked(rrd_file, synthetic):
    _, records = synthetic
    chunks = _chunks(rrd_file)
    probe = [r.step for r in records if r.phase == "probe"]
    assert probe == [1, 2, 3]
    steps, t1 = _column(chunks["/control/probing/T1"], "Scalars:scalars")
    assert steps == probe and [v[0] for v in t1] == [records[k].T1 for k in probe]
    # The rod is drawn in another colour while probing.
    steps, colors = _column(chunks["/world/rod"], "LineStrips2D:colors")
    by_step = dict(zip(steps, (c[0] for c in colors), strict=True))
    assert len({by_step[k] for k in probe}) == 1
    assert by_step[1] != by_step[0] and by_step[1] != by_step[5] and by_step[0] == by_step[5]


def _view_contents(path) -> list[dict[str, list[str]]]:
    """Per blueprint: view name -> its contents query."""
    reader = RrdReader(path)
    out = []
    for store in reader.blueprints():
        names, queries = {}, {}
        for ch in reader.stream(store=store):
            rb = ch.to_record_batch()
            if "ViewBlueprint:display_name" in rb.schema.names:
                names[ch.entity_path] = rb.column("ViewBlueprint:display_name").to_pylist()[0][0]
            if "ViewContents:query" in rb.schema.names:
                view = ch.entity_path.rsplit("/", 1)[0]
                queries[view] = rb.column("ViewContents:query").to_pylist()[0]
        out.append({names[v]: q for v, q in queries.items()})
    return out


def test_translation_and_rotation_commands_are_plotted_apart(rrd_file):
    for views in _view_contents(rrd_file):
        [theta] = [name for name, q in views.items() if "/control/u/theta" in q]
        [xy] = [name for name, q in views.items() if "/control/u/x" in q]
        assert theta != xy and "/control/u/y" in views[xy] and "/control/u/x" not in views[theta]
        assert "(rad" in theta and "(m" in xy


def _static(chunks, entity, component):
    [value] = [
        ch.to_record_batch().column(component).to_pylist()[0]
        for ch in chunks[entity]
        if ch.is_static and component in ch.to_record_batch().schema.names
    ]
    return value


def test_camera_labels_keep_off_the_rod_and_the_target_shows_at_convergence(rrd_file, synthetic):
    header, records = synthetic
    chunks = _chunks(rrd_file)
    for entity in ("/camera/target", "/world/target"):  # a line's label sits on the rod
        names = set().union(*(ch.to_record_batch().schema.names for ch in chunks[entity]))
        assert "LineStrips2D:labels" not in names, entity
    labels = _static(chunks, "/camera/legend", "Points2D:labels")
    assert labels == ["target", "truth (projected)", "extracted"]
    spots = np.asarray(_static(chunks, "/camera/legend", "Points2D:positions"))
    rod = np.concatenate([header.target_pixels] + [r.extracted for r in records])
    gap = np.linalg.norm(spots[:, None, :] - rod[None, :, :], axis=2).min()
    assert gap > 40, gap  # px: the legend is clear of every line the camera view draws
    # Lying on one another at convergence, each band is narrower than the one under it.
    radii = [
        _static(chunks, f"/camera/{e}", "LineStrips2D:radii")[0]
        for e in ("target", "projected_truth", "centerline")
    ]
    assert radii[0] > radii[1] > radii[2], radii


@pytest.fixture(scope="module")
def dual_arm(tmp_path_factory, helpers):
    """A dual-arm synthetic run (q = 6, a Jacobian error on every step after the first)."""
    run = SyntheticRun(seed=5, image_every=0, arms=2)
    records = run.records(12)
    path = tmp_path_factory.mktemp("rrd-dual") / "run.rrd"
    helpers.write_run(RerunSink, path, run.header, records, helpers.summary_of(records))
    return path, run.header, records


def test_dual_arm_logs_every_command_component_named_by_end(dual_arm):
    path, _, records = dual_arm
    chunks = _chunks(path)
    entities = [f"/control/u/{a}" for a in ("x", "y", "theta")]
    entities += [f"/control/u/x0_end/{a}" for a in ("x", "y", "theta")]
    for i, entity in enumerate(entities):
        steps, values = _column(chunks[entity], "Scalars:scalars")
        assert steps == [r.step for r in records], entity
        assert [v[0] for v in values] == [r.u[i] for r in records], entity
    names = [_static(chunks, e, "SeriesLines:names")[0] for e in entities]
    assert names[:3] == ["gripper Δx (m)", "gripper Δy (m)", "gripper Δθ (rad)"]
    assert names[3:] == ["x0 end Δx (m)", "x0 end Δy (m)", "x0 end Δθ (rad)"]
    for views in _view_contents(path):  # both ends on the translation and the rotation plots
        [xy] = [q for name, q in views.items() if name.startswith("command: translation")]
        [theta] = [q for name, q in views.items() if name.startswith("command: rotation")]
        assert {"/control/u/x0_end/x", "/control/u/x0_end/y"} <= set(xy)
        assert "/control/u/x0_end/theta" in theta and "/control/u/x0_end/theta" not in xy
    # The two ends' arrows are labelled; the static point is where the x0 end started.
    assert _static(chunks, "/world/clamp_arm", "Arrows2D:labels") == ["x0 end"]
    assert _static(chunks, "/world/gripper", "Arrows2D:labels") == ["gripper"]
    assert _static(chunks, "/world/clamp", "Points2D:labels") == ["x0 end at start"]
    steps, origins = _column(chunks["/world/clamp_arm"], "Arrows2D:origins")
    assert steps == [r.step for r in records]
    assert np.allclose(origins[-1][0], records[-1].clamp[:2] * [1, -1], atol=1e-6)


def test_jacobian_error_is_logged_where_a_step_has_one(dual_arm, rrd_file):
    path, _, records = dual_arm
    chunks = _chunks(path)
    steps, values = _column(chunks["/control/jacobian_error"], "Scalars:scalars")
    have = [r for r in records if np.isfinite(r.jacobian_error)]
    assert len(have) == len(records) - 1  # the initial step has none
    assert steps == [r.step for r in have]
    assert [v[0] for v in values] == [r.jacobian_error for r in have]
    # Its plot is in the layout sent at close (the run logged some), not in the first one
    # (the reader gives the two layouts in no fixed order).
    plots = sorted(
        [n for n, q in views.items() if "/control/jacobian_error" in q]
        for views in _view_contents(path)
    )
    assert plots == [[], ["Jacobian error ||J − J_true||_F / ||J_true||_F"]]
    # A run without Jacobian errors has neither the entity nor the plot.
    assert "/control/jacobian_error" not in _chunks(rrd_file)
    for views in _view_contents(rrd_file):
        assert not any("/control/jacobian_error" in q for q in views.values())
