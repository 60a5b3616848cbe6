"""The report page in a real browser (headless Chromium, tests/report/browser.py): it
loads without console errors, plays, scrubs to a frame and draws that frame's pose
(the BVH's within 1 mm), draws something, and an evaluation's table sorts and opens
its clips; a Bandai-Namco and a CMU clip (../shared/data) are on screen at frame 0,
with no bone from a root fixed at the origin; the timeline tells clip names of one
prefix apart. The README's screenshot (docs/report.png) is made here from the README's
demo (procedural data): GRAPHSVC_UPDATE_SCREENSHOT=1 rewrites it."""

import io
import json
import os
from pathlib import Path

import numpy as np
import pytest

from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.library import load_motion
from graphsvc.strategies import available
from tests.report.browser import console_errors, open_page, start_browser, wait_for

SCREENSHOT = Path(__file__).resolve().parents[2] / "docs" / "report.png"


@pytest.fixture(scope="module")
def driver():
    d = start_browser()
    yield d
    d.quit()


def _png(data: bytes):
    from PIL import Image

    return Image.open(io.BytesIO(data)).convert("RGB")


def test_demo_page_plays_scrubs_and_draws_the_bvh_pose(driver, demo_run, tmp_path):
    _, out = demo_run
    open_page(driver, out / "report.html")
    assert console_errors(driver) == []
    hook = "return window.graphsvcViewer."
    assert driver.execute_script(hook + "figures()") == ["reconstruction", "truth"]
    legend = driver.find_element("id", "legend").text  # what this page draws, no more
    assert "green: truth" in legend and "markers" not in legend
    T = driver.execute_script(hook + "frames()")
    recon, truth = load_motion(out / "reconstruction.bvh"), load_motion(out / "performance.bvh")
    assert T == recon.num_frames == truth.num_frames

    # Played, the drawn frame number advances.
    label = driver.find_element("id", "frame-number")
    before = label.text
    assert before == f"frame 0 / {T - 1}"
    driver.find_element("id", "play").click()
    assert wait_for(lambda: label.text != before), "the animation did not advance"
    driver.find_element("id", "play").click()  # (pause)
    assert driver.execute_script(hook + "playing()") is False

    # Scrubbed with the slider, the page draws that frame's pose: the BVH's, within 1 mm.
    _, recon_world = motion_fk(recon)
    _, truth_world = motion_fk(truth)
    for frame in (T // 3, T - 1):
        driver.execute_script(
            "const s = document.getElementById('scrub'); s.value = arguments[0];s.dispatchEvent(new Event('input'));",
            frame,
        )
        assert driver.execute_script(hook + "frame()") == frame
        assert label.text == f"frame {frame} / {T - 1}"
        for fig, world in ((0, recon_world), (1, truth_world)):
            drawn = np.array(driver.execute_script(hook + "drawnJointPositions(arguments[0])", fig))
            assert np.linalg.norm(drawn - world[frame], axis=1).max() < 0.001
            held = np.array(driver.execute_script(hook + "jointPositions(arguments[0], arguments[1])", frame, fig))
            assert np.linalg.norm(held - world[frame], axis=1).max() < 0.001

    # A screenshot of the viewer is not blank: skeletons and grid over the background.
    driver.execute_script(hook + "setFrame(arguments[0])", int(T * 0.3))
    view = _png(driver.find_element("id", "view").screenshot_as_png)
    pixels = np.asarray(view).reshape(-1, 3).astype(int)
    background = np.array([0xF4, 0xF5, 0xF7])
    assert np.mean(np.abs(pixels - background).sum(axis=1) > 30) > 0.01
    blue = (pixels[:, 2] > 150) & (pixels[:, 0] < 120)  # (the reconstruction's lines)
    green = (pixels[:, 1] > 120) & (pixels[:, 0] < 100) & (pixels[:, 2] < 120)  # (the truth's)
    assert blue.sum() > 50 and green.sum() > 50
    assert console_errors(driver) == []

    if os.environ.get("GRAPHSVC_UPDATE_SCREENSHOT"):  # from the README's demo (its default three minutes)
        from graphsvc.demo import run_demo

        run_demo(tmp_path / "readme", seed=0)
        open_page(driver, tmp_path / "readme" / "report.html")
        driver.execute_script(hook + "setFrame(arguments[0])", int(driver.execute_script(hook + "frames()") * 0.3))
        page = _png(driver.get_screenshot_as_png())
        page = page.crop((0, 0, page.width, min(page.height, 1060)))
        page = page.resize((page.width * 3 // 4, page.height * 3 // 4))
        page.quantize(colors=160).save(SCREENSHOT, optimize=True)
    assert SCREENSHOT.is_file() and SCREENSHOT.stat().st_size < 150_000


def test_evaluation_table_sorts_and_opens_each_clip(driver, tmp_path, capsys):
    from graphsvc.cli import main
    from tests.conftest import write_procedural_kb

    (tmp_path / "kb").mkdir()
    kb = write_procedural_kb(tmp_path / "kb", seed=5, minutes=0.4)
    clips = sorted(p.name for p in kb.glob("*.bvh"))[:3]
    assert (
        main(
            [
                "evaluate",
                str(kb),
                "--test",
                ",".join(clips),
                "--layout",
                "kelly6",
                "--hold-out",
                "clip",
                "--quiet",
                "--json",
                str(tmp_path / "eval.json"),
                "--report-html",
                str(tmp_path / "eval.html"),
            ]
        )
        == 0
    )
    capsys.readouterr()
    rows = json.loads((tmp_path / "eval.json").read_text())["clips"]
    open_page(driver, tmp_path / "eval.html")
    assert console_errors(driver) == []
    table = driver.find_element("id", "clips")

    def first_column():
        return [tr.find_elements("tag name", "td")[0].text for tr in table.find_elements("css selector", "tbody tr")]

    assert first_column() == [r["name"] for r in rows]
    header = table.find_elements("css selector", "thead th")
    assert [h.text for h in header][:4] == ["clip", "label", "frames", "joint_err_cm"]
    header[3].click()  # joint error, ascending, then descending
    by_error = [r["name"] for r in sorted(rows, key=lambda r: r["joint_err_cm"])]
    assert first_column() == by_error
    header[3].click()
    assert first_column() == by_error[::-1]

    # Each row opens its clip in the viewer.
    for tr in table.find_elements("css selector", "tbody tr"):
        name = tr.find_elements("tag name", "td")[0].text
        tr.click()
        k = [r["name"] for r in rows].index(name)
        assert driver.execute_script("return window.graphsvcViewer.clip()") == k
        assert driver.find_element("id", "clip-name").text == name
        assert driver.execute_script("return window.graphsvcViewer.frames()") == rows[k]["frames"]
    assert console_errors(driver) == []


@pytest.mark.parametrize("strategy", [n for n in available() if n != "multilinear"])  # (test_report_files says why)
def test_every_strategys_page_runs_and_seeks_from_its_charts(driver, files, strategy, tmp_path):
    from graphsvc.motion.bvh import write_bvh
    from graphsvc.pipeline import Options, Weights, synthesize_files
    from graphsvc.report.html import write_html
    from graphsvc.report.load import load_document

    d, graph, truth = files
    rec = d / ("markers.rec" if strategy == "ssg" else "take.rec")
    synthesize_files(
        graph,
        d / "kb.graph",
        rec,
        tmp_path / "out.bvh",
        Options(strategy=strategy, weights=Weights(0.5, 1, 1)),
        report_path=tmp_path / "out.json",
    )
    write_bvh(tmp_path / "truth.bvh", truth, scale=100.0)
    write_html(tmp_path / "page.html", load_document(tmp_path / "out.json", truth=tmp_path / "truth.bvh"))
    open_page(driver, tmp_path / "page.html")
    assert console_errors(driver) == []
    hook = "return window.graphsvcViewer."
    T = driver.execute_script(hook + "frames()")
    assert ("orange: measured markers" in driver.find_element("id", "legend").text) == (strategy == "ssg")
    # A click on the timeline seeks to the frame under it.
    timeline = driver.find_element("id", "timeline")
    from selenium.webdriver.common.action_chains import ActionChains

    width = timeline.size["width"]
    ActionChains(driver).move_to_element_with_offset(timeline, int(width * 0.3), 0).click().perform()
    x = width / 2 + int(width * 0.3)  # (offsets are from the element's centre)
    expected = round((x - 150) / (width - 160) * (T - 1))
    assert abs(driver.execute_script(hook + "frame()") - expected) <= 1
    # Overlaid, the truth is drawn where it is (no side-by-side offset).
    select = driver.find_element("id", "layout")
    driver.execute_script("arguments[0].value = 'overlay'; arguments[0].dispatchEvent(new Event('change'));", select)
    frame = driver.execute_script(hook + "frame()")
    drawn = np.array(
        driver.execute_script("return document.getElementById('view') && graphsvcViewer.drawnJointPositions(1)")
    )
    _, world = motion_fk(truth)
    assert np.abs(drawn - world[frame]).max() < 0.001
    assert console_errors(driver) == []


# ---------------------------------------------------------------- real skeletons (../shared/data)


def _motion_page(motion, path, truth=None, timeline=None):
    """A report page of `motion` (and `truth`) made with gather's functions, no graph."""
    from graphsvc.report.gather import clip_view
    from graphsvc.report.html import write_html
    from graphsvc.strategies.sources import timeline_from_labels

    if timeline is None:
        timeline = timeline_from_labels([{"label": "clip", "start_frame": 0, "frames": motion.num_frames}])
    view = clip_view(motion.name, motion, timeline, truth=truth)
    write_html(path, {"title": motion.name, "clips": [view], "table": None})
    return path


def _bandai_walk(data_dir):
    path = data_dir / "bandai" / "dataset-2" / "data" / "dataset-2_walk_active_004.bvh"
    if not path.is_file():
        pytest.skip(f"{path} not found (the Bandai-Namco walk the test draws)")
    return load_motion(path).slice(0, 45), "Hips"


def _cmu_walk(data_dir):
    path = data_dir / "cmu" / "02" / "02_01.amc"
    if not path.is_file():
        pytest.skip(f"{path} not found (the CMU walk the test draws)")
    return load_motion(path).slice(0, 60), "root"


@pytest.mark.parametrize("source", [_bandai_walk, _cmu_walk], ids=["bandai", "cmu"])
def test_a_real_clips_figures_are_on_screen_at_frame_0(driver, data_dir, tmp_path, source):
    """The page follows the pelvis (Bandai-Namco's `Hips`, CMU's `root`): at frame 0 both
    figures' drawn joints are inside the viewer, around its middle, and no bone is drawn
    from a joint that stays put over the clip (Bandai-Namco's `joint_Root`, at the origin
    while the walk starts more than 5 m from it)."""
    motion, pelvis_name = source(data_dir)
    names = list(motion.skeleton.names)
    parents = motion.skeleton.parents
    pelvis = names.index(pelvis_name)
    _, world = motion_fk(motion)
    fixed = {j for j in range(len(names)) if np.ptp(world[:, j], axis=0).max() < 0.001}
    above = set()  # (the pelvis's ancestors)
    j = int(parents[pelvis])
    while j >= 0:
        above.add(j)
        j = int(parents[j])
    if pelvis_name == "Hips":  # (what makes the case: a fixed root far from the figure)
        assert above == fixed == {names.index("joint_Root")}
        assert np.linalg.norm(world[0, pelvis, [0, 2]]) > 5.0
    open_page(driver, _motion_page(motion, tmp_path / "page.html", truth=motion))
    assert console_errors(driver) == []
    hook = "return window.graphsvcViewer."
    assert driver.execute_script(hook + "frame()") == 0
    shown = [j for j in range(len(names)) if j not in above]
    expected_bones = sorted((int(parents[j]), j) for j in shown if parents[j] >= 0 and parents[j] not in above)
    pelvis_ndc = []
    for fig in (0, 1):
        assert driver.execute_script(hook + "centre(arguments[0])", fig) == pelvis
        bones = sorted(tuple(b) for b in driver.execute_script(hook + "drawnBones(arguments[0])", fig))
        assert bones == expected_bones
        assert not any(a in fixed for a, _ in bones)
        drawn = driver.execute_script(hook + "drawnJointPositions(arguments[0])", fig)
        assert [j for j, p in enumerate(drawn) if p is None] == sorted(above)
        assert np.abs(np.array([drawn[j] for j in shown]) - world[0, shown]).max() < 0.001
        ndc = driver.execute_script(hook + "projectedJoints(arguments[0])", fig)
        points = np.array([ndc[j] for j in shown])
        assert (np.abs(points[:, :2]) < 1).all(), f"figure {fig}: joints off screen at frame 0: {points[:, :2]}"
        assert (np.abs(points[:, 2]) < 1).all()  # (between the near and far planes)
        pelvis_ndc.append(ndc[pelvis])
    # The camera looks at the middle of the two pelvises (side by side, 1.5 m apart).
    middle = np.mean(pelvis_ndc, axis=0)
    assert abs(middle[0]) < 0.1 and abs(middle[1]) < 0.25, middle
    # The screenshot has both figures' colours.
    pixels = np.asarray(_png(driver.find_element("id", "view").screenshot_as_png)).reshape(-1, 3).astype(int)
    blue = (pixels[:, 2] > 150) & (pixels[:, 0] < 120)
    green = (pixels[:, 1] > 120) & (pixels[:, 0] < 100) & (pixels[:, 2] < 120)
    assert blue.sum() > 50 and green.sum() > 50
    assert console_errors(driver) == []


def _fitted(text: str, full: str) -> bool:
    """`text` is `full`, or `full` cut in the middle with an ellipsis."""
    if text == full:
        return True
    head, sep, tail = text.partition("…")
    return sep == "…" and len(head) >= 1 and len(tail) >= 1 and full.startswith(head) and full.endswith(tail)


def test_timeline_tells_clips_of_one_prefix_apart(driver, tmp_path):
    """Bandai-Namco clip names all start "dataset-2_": the timeline writes them without
    it, cut in the middle where a run is narrow, and the neighbours' rows alike."""
    from graphsvc.strategies.sources import timeline_from_sources
    from tests.conftest import still_motion

    names = ["dataset-2_walk_active_001", "dataset-2_run_active_003", "dataset-2_walk-turn-left_normal_002"]
    T = 90
    lead = np.array([0] * 40 + [1] * 4 + [2] * 46)  # (the second run 4 frames: about 40 px wide)
    clip = np.stack([lead, np.full(T, -1)], axis=1)
    frame = np.stack([np.arange(T, dtype=float), np.zeros(T)], axis=1)
    weight = np.stack([np.ones(T), np.zeros(T)], axis=1)
    timeline = timeline_from_sources(names, ["walk"] * T, clip, frame, weight)
    open_page(driver, _motion_page(still_motion(T), tmp_path / "page.html", timeline=timeline))
    assert console_errors(driver) == []
    drawn = driver.execute_script("""
        const texts = [], fill = CanvasRenderingContext2D.prototype.fillText;
        CanvasRenderingContext2D.prototype.fillText = function (t, x, y) {
          if (this.canvas.id === "timeline") texts.push([String(t), x, y, this.measureText(t).width]);
          return fill.apply(this, arguments);
        };
        window.graphsvcViewer.loadClip(0);
        CanvasRenderingContext2D.prototype.fillText = fill;
        return texts;""")
    row0 = [(t, x, w) for t, x, y, w in drawn if y < 22 and x > 100]  # (the runs' names, right of the row names)
    short = [n[len("dataset-2_") :] for n in names]
    assert [t for t, _, _ in row0][::2] == [short[0], short[2]]  # (wide runs: the whole name but the prefix)
    narrow, x, width = row0[1]
    assert _fitted(narrow, short[1]) and narrow != short[1] and "…" in narrow, narrow
    width_px = driver.execute_script("""
        const c = document.getElementById("timeline");
        return (c.width - 160) * 4 / 89;""")
    assert width <= width_px
    # The neighbours' rows (left of the chart, 138 px): all three, told apart.
    rows = [t for t, x, y, w in drawn if x == 6 and y > 44]
    assert len(rows) == 3 and len(set(rows)) == 3
    assert all(any(_fitted(t, s) for s in short) for t in rows), rows
    assert "dataset-2_" in driver.find_element("id", "timeline-legend").text
    assert console_errors(driver) == []
