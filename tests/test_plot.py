"""The figure commands: what the learning curves, the positional-embedding t-SNE and the relational-bias
heatmaps show (lines, bands, panels, points, labels, the CSV's numbers), and their errors."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.legend import Legend

from swat_jax.morphology import load, relation_features
from swat_jax.plot import (
    CurvePoint,
    curves_figure,
    embeddings_figure,
    main,
    plot_curves,
    plot_embeddings,
    plot_relations,
    require_embedding,
)
from swat_jax.runs.config import TrainConfig, load_config
from swat_jax.runs.metrics import read_metrics
from swat_jax.runs.trained import load_policy

HOPPERS = ("hopper_3", "hopper_4", "hopper_5")
WALKERS = ("walker_2_main", "walker_4_main")


def synthetic_run(directory: Path, env: str, algo: str, seeds: list[int], bodies: tuple[str, ...]) -> Path:
    """A run directory with config.json and a metrics.csv of known returns: seed s of ``algo`` returns
    steps / 100 + 10 s (+ 1000 for amorpheus) on every body at 100, 200 and 300 steps, except that seed 1
    has no finished episode at 200 steps (empty cells)."""
    directory.mkdir()
    config = TrainConfig(env=env, algo=algo, seed=seeds[0], seeds=len(seeds), run_dir=str(directory))
    (directory / "config.json").write_text(config.to_json())
    columns = ["env_steps", "seed", "mean_return", *(f"return/{body}" for body in bodies)]
    with (directory / "metrics.csv").open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(columns)
        for steps in (100, 200, 300):
            for seed in seeds:
                value = steps / 100 + 10 * seed + (1000 if algo == "amorpheus" else 0)
                cell = "" if (seed == 1 and steps == 200) else value
                writer.writerow([steps, seed, *[cell] * (len(columns) - 2)])
    return directory


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as file:
        return list(csv.DictReader(file))


def mean_and_error(values: list[float]) -> tuple[float, float]:
    """Mean and standard error (sample standard deviation / sqrt(n); NaN for one value)."""
    array = np.array(values, np.float64)
    error = np.std(array, ddof=1) / math.sqrt(len(array)) if len(array) > 1 else math.nan
    return float(np.mean(array)), float(error)


def assert_csv_point(row: dict[str, str], values: list[float]) -> None:
    mean, error = mean_and_error(values)
    assert int(row["seeds"]) == len(values)
    assert float(row["mean"]) == pytest.approx(mean, rel=1e-9)
    if math.isnan(error):
        assert row["standard_error"] == ""
    else:
        assert float(row["standard_error"]) == pytest.approx(error, rel=1e-9)


def legend_texts(axes) -> list[str]:
    return [text.get_text() for text in axes.get_legend().get_texts()]


def test_curves_pool_seeds_per_algorithm_and_set_with_a_panel_per_set(tmp_path):
    runs = [
        synthetic_run(tmp_path / "hopper-swat-a", "hopper", "swat", [0, 1], HOPPERS),
        synthetic_run(tmp_path / "hopper-amorpheus", "hopper", "amorpheus", [0, 1], HOPPERS),
        synthetic_run(tmp_path / "hopper-swat-b", "hopper", "swat", [2], HOPPERS),
        synthetic_run(tmp_path / "walker-swat", "walker", "swat", [0, 1], WALKERS),
    ]
    figure = plot_curves(runs, tmp_path / "figs" / "curves.png")
    assert (tmp_path / "figs" / "curves.png").stat().st_size > 0
    hopper, walker = figure.axes
    assert [hopper.get_title(), walker.get_title()] == ["hopper", "walker"]
    assert legend_texts(hopper) == ["swat", "amorpheus"] and legend_texts(walker) == ["swat"]
    assert len(hopper.collections) == 2 and len(walker.collections) == 1, "a band per line"
    swat_line = hopper.get_lines()[0]
    np.testing.assert_array_equal(swat_line.get_xdata(), [100, 200, 300])
    # swat seeds 0 and 1 of one run and seed 2 of another are pooled; seed 1 has no value at 200 steps
    np.testing.assert_allclose(swat_line.get_ydata(), [11.0, 12.0, 13.0])
    rows = read_csv(tmp_path / "figs" / "curves.csv")
    assert list(rows[0]) == ["panel", "algorithm", "env_steps", "mean", "standard_error", "seeds"]
    point = {(row["panel"], row["algorithm"], int(row["env_steps"])): row for row in rows}
    assert len(point) == len(rows) == 9
    assert_csv_point(point["hopper", "swat", 100], [1, 11, 21])
    assert_csv_point(point["hopper", "swat", 200], [2, 22])
    assert_csv_point(point["hopper", "amorpheus", 300], [1003, 1013])
    assert_csv_point(point["walker", "swat", 200], [2])


def test_curves_label_their_step_ticks_in_thousands_so_that_six_digits_do_not_overlap():
    points = [CurvePoint("3D Hopper++", "swat", steps, 100.0, 1.0, 2) for steps in range(0, 160_000, 10_000)]
    axes = curves_figure(points, "train").axes[0]
    axes.figure.canvas.draw()
    labels = [label.get_text() for label in axes.get_xticklabels() if label.get_text()]
    assert "150k" in labels and all(len(label) <= 4 for label in labels), labels


def test_per_body_curves_add_a_panel_per_body(tmp_path):
    runs = [
        synthetic_run(tmp_path / "hopper", "hopper", "swat", [0, 1], HOPPERS),
        synthetic_run(tmp_path / "walker", "walker", "smp", [0, 1], WALKERS),
    ]
    figure = plot_curves(runs, tmp_path / "bodies.png", per_body=True)
    titles = [axes.get_title() for axes in figure.axes]
    assert titles == [
        "hopper",
        *(f"hopper: {body}" for body in HOPPERS),
        "walker",
        *(f"walker: {body}" for body in WALKERS),
    ]
    assert legend_texts(figure.axes[-1]) == ["smp"]
    rows = read_csv(tmp_path / "bodies.csv")
    assert {row["panel"] for row in rows} == set(titles)


def test_curves_of_a_trained_run_are_the_mean_and_error_over_its_seeds(trained_run, tmp_path):
    metrics = read_metrics(trained_run)
    panel = Path(load_config(trained_run / "config.json").env).name
    for metric, column in (("train", "mean_return"), ("eval", "eval/mean_return")):
        output = tmp_path / f"{metric}.png"
        assert main(["curves", str(trained_run), "-o", str(output), "--metric", metric]) == 0
        assert output.stat().st_size > 0
        rows = read_csv(output.with_suffix(".csv"))
        steps = sorted({row["env_steps"] for row in metrics if math.isfinite(row[column])})
        assert [float(row["env_steps"]) for row in rows] == steps
        for row in rows:
            values = [
                m[column]
                for m in metrics
                if m["env_steps"] == float(row["env_steps"]) and math.isfinite(m[column])
            ]
            assert (row["panel"], row["algorithm"]) == (panel, "amorpheus")
            assert_csv_point(row, values)
    assert [float(row["env_steps"]) for row in read_csv(tmp_path / "eval.csv")] == [400, 600]


def test_curves_refuse_a_folder_that_is_not_a_run_and_missing_eval_metrics(tmp_path, capsys):
    run = synthetic_run(tmp_path / "no-eval", "hopper", "swat", [0], HOPPERS)
    assert main(["curves", str(run), "-o", str(tmp_path / "f.png"), "--metric", "eval"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("error: ") and "eval/mean_return" in error and "--eval-interval" in error
    (tmp_path / "empty").mkdir()
    assert main(["curves", str(run), str(tmp_path / "empty"), "-o", str(tmp_path / "f.png")]) == 2
    assert "not a run directory" in capsys.readouterr().err
    assert not (tmp_path / "f.png").exists()


def test_embedding_figure_has_a_point_per_limb_marked_by_body_and_coloured_by_type(
    trained_swat_run, tmp_path
):
    figure = plot_embeddings(trained_swat_run, tmp_path / "pe.png")
    assert (tmp_path / "pe.png").stat().st_size > 0
    [axes] = figure.axes
    [hopper] = axes.collections
    assert len(hopper.get_offsets()) == load("hopper_3").num_limbs
    assert np.isfinite(hopper.get_offsets()).all()
    assert len({tuple(colour) for colour in hopper.get_facecolors()}) == 3, "torso, thigh and foot"
    legends = [child for child in axes.get_children() if isinstance(child, Legend)]
    texts = {legend.get_title().get_text(): [t.get_text() for t in legend.get_texts()] for legend in legends}
    assert texts == {"body": ["hopper_3"], "limb type": ["torso", "thigh", "foot"]}


def test_embedding_figure_of_many_bodies_gives_each_body_its_marker():
    bodies = [load("hopper_3"), load("walker_4_main"), load("nervenet_hopper")]
    total = sum(body.num_limbs for body in bodies)
    figure = embeddings_figure(np.random.default_rng(0).normal(size=(total, 2)), bodies, "test")
    collections = figure.axes[0].collections
    assert [len(c.get_offsets()) for c in collections] == [body.num_limbs for body in bodies]
    markers = [c.get_paths()[0].vertices.tobytes() for c in collections]
    assert len(set(markers)) == len(bodies)


def test_relations_figure_is_a_heatmap_of_g_per_head_labelled_with_limb_names(trained_swat_run, tmp_path):
    figure = plot_relations(trained_swat_run, "hopper_3", tmp_path / "re.png")
    assert (tmp_path / "re.png").stat().st_size > 0
    heatmaps = [(axes, image) for axes in figure.axes for image in axes.images]
    kernel = np.asarray(
        load_policy(trained_swat_run).seed_params(0)["params"]["policy"]["relational_embedding"]["g"][
            "kernel"
        ]
    )
    assert len(heatmaps) == kernel.shape[1] == 2, "one heatmap per head"
    body = load("hopper_3")
    relations = relation_features(body.parents)
    for head, (axes, image) in enumerate(heatmaps):
        assert [t.get_text() for t in axes.get_xticklabels()] == list(body.limb_names)
        assert [t.get_text() for t in axes.get_yticklabels()] == list(body.limb_names)
        np.testing.assert_allclose(image.get_array(), relations @ kernel[:, head], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ("nervenet_hopper", ["21 observation features", "trained on 19"]),
        ("humanoid_2d_9_full", ["9 limbs", "--network.max-traversal-positions 9"]),
        ("no_such_body", ["no_such_body"]),
    ],
)
def test_relations_refuse_bodies_the_policy_cannot_take(trained_swat_run, tmp_path, capsys, body, expected):
    assert main(["relations", str(trained_swat_run), "--body", body, "-o", str(tmp_path / "re.png")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("error: ") and all(part in error for part in expected), error
    assert not (tmp_path / "re.png").exists()


def test_figures_of_embeddings_refuse_a_network_without_them(trained_run, trained_swat_run, tmp_path, capsys):
    output = str(tmp_path / "x.png")
    assert main(["embeddings", str(trained_run), "-o", output]) == 2
    error = capsys.readouterr().err
    assert "amorpheus" in error and "positional embedding" in error
    assert main(["relations", str(trained_run), "--body", "hopper_3", "-o", output]) == 2
    error = capsys.readouterr().err
    assert "amorpheus" in error and "relational embedding" in error
    assert main(["embeddings", str(trained_swat_run), "-o", output, "--seed-index", "1"]) == 2
    assert "--seed-index 1" in capsys.readouterr().err
    assert not Path(output).exists()


@pytest.mark.parametrize(
    ("module", "without", "with_it"),
    [
        ("traversal_embedding", ("amorpheus", "smp", "swat_no_pe", "swat_no_pe_re"), ("swat", "swat_no_re")),
        ("relational_embedding", ("amorpheus", "smp", "swat_no_re", "swat_no_pe_re"), ("swat", "swat_no_pe")),
    ],
)
def test_only_networks_with_the_embedding_are_accepted(module, without, with_it):
    for algo in with_it:
        require_embedding(TrainConfig(env="hopper", algo=algo), Path("run"), module)
    for algo in without:
        with pytest.raises(ValueError, match=f"run trained {algo}, whose network has no"):
            require_embedding(TrainConfig(env="hopper", algo=algo), Path("run"), module)
