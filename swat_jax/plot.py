"""The paper's figures from run directories: ``python -m swat_jax.plot curves|embeddings|relations|diagnostics``.

  curves      return against environment steps (Figures 4-6): the mean over a set's bodies, mean ±
              standard error over seeds as a band, a line per algorithm and a panel per set
              (``--per-body``: and a panel per body); the plotted numbers go beside the PNG as CSV
  embeddings  Figure 8: a t-SNE of every limb's traversal-based positional embedding (section 4.1) over
              the set's train and test bodies, marker by body, colour by limb type
  relations   Figures 9-11: the learned relational bias g(R) of each head (section 4.2, eq. 4) on one
              body, an n x n heatmap per head labelled with the limb names
  diagnostics one run's learning diagnostics (return, episode length, the critics' estimate against the
              return, the twins' disagreement, saturated actions, the exploration noise applied, the update
              share): a row per diagnostic, a column per body, a line per seed

Figures are drawn off-screen with matplotlib's Agg canvas (no display, no pyplot state); every
``plot_*`` function saves a PNG and returns the matplotlib Figure. Bad input exits with status 2.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Literal, get_args

import jax
import numpy as np
import tyro
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import EngFormatter
from sklearn.manifold import TSNE

from swat_jax.cli import run_command
from swat_jax.compilation_cache import enable_caches
from swat_jax.morphology import Morphology, MorphologyError, StructureBatch, get_set, load
from swat_jax.networks.transformer import RelationalEmbedding, TraversalEmbedding
from swat_jax.runs.checkpoint import CheckpointError
from swat_jax.runs.config import CONFIG_FILE, ConfigError, TrainConfig, load_config
from swat_jax.runs.metrics import CSV_FILE, read_metrics, standard_error
from swat_jax.runs.trained import TrainedPolicy, load_policy

Metric = Literal["train", "eval"]
METRIC_PREFIXES = dict(zip(get_args(Metric), ("", "eval/"), strict=True))
"""Column prefix of each ``--metric``: the training episodes' returns (the paper's curves) or the
deterministic evaluations during training."""
CSV_COLUMNS = ("panel", "algorithm", "env_steps", "mean", "standard_error", "seeds")
PANEL_COLUMNS = 3
PANEL_SIZE = (4.8, 3.6)
FILLED_MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">", "h", "p", "8")
LINE_MARKERS = ("1", "2", "3", "4", "+", "x", "|", "_")
BODY_STYLES = tuple((marker, True) for marker in FILLED_MARKERS + LINE_MARKERS) + tuple(
    (marker, False) for marker in FILLED_MARKERS
)
"""(marker, filled) of each body in the embedding figure: 34 distinct styles (CWHH++ has 33 bodies),
repeated after that."""
LEGEND_ROWS = 18
PERPLEXITY = 30.0
"""t-SNE perplexity (scikit-learn's default), lowered below the number of limbs for small sets."""
TSNE_RANDOM_STATE = 0
EMBEDDINGS = {
    "traversal_embedding": (
        "traversals",
        "traversal-based positional embedding (<traversal>_order tables)",
        "swat or swat_no_re",
    ),
    "relational_embedding": ("relations", "relational embedding (g)", "swat or swat_no_pe"),
}
"""Per embedding module of SWAT's actor: the NetworkConfig field that turns it on, what it is, and the
algorithms that have it."""


# Learning curves (Figures 4-6)


@dataclasses.dataclass(frozen=True)
class RunMetrics:
    """A run directory's configuration and its metrics rows (one per seed per log interval)."""

    config: TrainConfig
    rows: list[dict[str, float]]

    @property
    def algorithm(self) -> str:
        """The line this run belongs to: its algorithm, marked when it started from another run."""
        return f"{self.config.algo} (transfer)" if self.config.init_from else self.config.algo

    @property
    def panel(self) -> str:
        """The panel this run belongs to: its set, and the split when it did not train on the train bodies."""
        name = Path(self.config.env).name
        if self.config.bodies:
            return f"{name} ({', '.join(Path(body).stem for body in self.config.bodies)})"
        return name if self.config.split == "train" else f"{name} ({self.config.split} bodies)"

    def body_labels(self, metric: str) -> list[str]:
        """The bodies with a return column for ``metric``, in the CSV's order."""
        prefix = f"{METRIC_PREFIXES[metric]}return/"
        return [column.removeprefix(prefix) for column in self.rows[0] if column.startswith(prefix)]


@dataclasses.dataclass(frozen=True)
class CurvePoint:
    """One plotted point: the mean and standard error over seeds (NaN for one seed) at ``env_steps``."""

    panel: str
    algorithm: str
    env_steps: int
    mean: float
    standard_error: float
    seeds: int


def read_run_metrics(run_dir: Path, metric: str) -> RunMetrics:
    """The config and metrics of ``run_dir``; ConfigError if it is not a run or lacks ``metric``'s columns."""
    run_dir = Path(run_dir)
    if not (run_dir / CONFIG_FILE).is_file():
        raise ConfigError(
            f"{run_dir}: not a run directory (no {CONFIG_FILE}); give folders written by swat_jax.train"
        )
    config = load_config(run_dir / CONFIG_FILE)
    if not (run_dir / CSV_FILE).is_file():
        raise ConfigError(
            f"{run_dir}: no {CSV_FILE} yet; it is written at the first log interval of training"
        )
    rows = read_metrics(run_dir)
    if rows and "seed" not in rows[0]:
        raise ConfigError(f"{run_dir}: {CSV_FILE} has no seed column (written before runs had a seed axis)")
    column = f"{METRIC_PREFIXES[metric]}mean_return"
    if not rows or not any(math.isfinite(row.get(column, math.nan)) for row in rows):
        fix = "train with --eval-interval, or plot --metric train" if metric == "eval" else "train longer"
        raise ConfigError(f"{run_dir}: no {column} values in {CSV_FILE}; {fix}")
    return RunMetrics(config, rows)


def seed_curves(runs: Sequence[RunMetrics], column: str) -> list[dict[int, float]]:
    """Per seed of every run, its finite values of ``column`` by environment step."""
    curves = []
    for run in runs:
        for seed in dict.fromkeys(row["seed"] for row in run.rows):
            values = {
                int(row["env_steps"]): row.get(column, math.nan) for row in run.rows if row["seed"] == seed
            }
            curves.append({step: value for step, value in values.items() if math.isfinite(value)})
    return curves


def summarise(panel: str, algorithm: str, curves: Sequence[dict[int, float]]) -> list[CurvePoint]:
    """At every step where a seed has a value, the mean and standard error over the seeds that have one."""
    points = []
    for step in sorted({step for curve in curves for step in curve}):
        values = np.array([curve[step] for curve in curves if step in curve], np.float64)
        points.append(
            CurvePoint(panel, algorithm, step, float(np.mean(values)), standard_error(values), len(values))
        )
    return points


def curve_points(runs: Sequence[RunMetrics], metric: str, per_body: bool) -> list[CurvePoint]:
    """Every plotted point: per panel (set, and with ``per_body`` each of its bodies) and algorithm, the
    seeds of all runs of that algorithm on that set pooled."""
    prefix = METRIC_PREFIXES[metric]
    groups: dict[tuple[str, str], list[RunMetrics]] = {}
    for run in runs:
        groups.setdefault((run.panel, run.algorithm), []).append(run)
    lines: dict[str, list[tuple[str, list[RunMetrics], str]]] = {}
    for (panel, algorithm), group in groups.items():
        lines.setdefault(panel, []).append((algorithm, group, f"{prefix}mean_return"))
        if per_body:
            for body in dict.fromkeys(body for run in group for body in run.body_labels(metric)):
                lines.setdefault(f"{panel}: {body}", []).append((algorithm, group, f"{prefix}return/{body}"))
    return [
        point
        for panel, panel_lines in lines.items()
        for algorithm, group, column in panel_lines
        for point in summarise(panel, algorithm, seed_curves(group, column))
    ]


def panel_grid(figure: Figure, count: int) -> list[Axes]:
    """``count`` axes in rows of up to PANEL_COLUMNS (no empty axes)."""
    columns = min(PANEL_COLUMNS, count)
    rows = math.ceil(count / columns)
    figure.set_size_inches(PANEL_SIZE[0] * columns, PANEL_SIZE[1] * rows)
    return [figure.add_subplot(rows, columns, index + 1) for index in range(count)]


def curves_figure(points: Sequence[CurvePoint], metric: str) -> Figure:
    """A panel per panel name, in order of appearance; per algorithm the mean line and a ± standard error band."""
    panels = list(dict.fromkeys(point.panel for point in points))
    algorithms = list(dict.fromkeys(point.algorithm for point in points))
    colours = {algorithm: f"C{index % 10}" for index, algorithm in enumerate(algorithms)}
    figure = new_figure()
    label = "return (deterministic evaluation)" if metric == "eval" else "return (training episodes)"
    for axes, panel in zip(panel_grid(figure, len(panels)), panels, strict=True):
        for algorithm in algorithms:
            line = [point for point in points if point.panel == panel and point.algorithm == algorithm]
            if line:
                draw_band(axes, line, algorithm, colours[algorithm])
        axes.set_title(panel)
        axes.set_xlabel("environment steps")
        axes.xaxis.set_major_formatter(EngFormatter(sep=""))  # 150k, not 150000: six digits a tick overlap
        axes.set_ylabel(label)
        axes.legend()
    figure.tight_layout()
    return figure


def draw_band(axes: Axes, line: Sequence[CurvePoint], algorithm: str, colour: str) -> None:
    """The mean over seeds as a line and mean ± standard error as a shaded band (absent for one seed)."""
    steps = np.array([point.env_steps for point in line])
    mean = np.array([point.mean for point in line])
    error = np.array([point.standard_error for point in line])
    axes.plot(steps, mean, color=colour, label=algorithm, marker="." if len(line) < 20 else None)
    axes.fill_between(steps, mean - error, mean + error, color=colour, alpha=0.25, linewidth=0)


def write_points_csv(points: Sequence[CurvePoint], path: Path) -> None:
    """The plotted numbers, a row per point (empty standard_error for one seed)."""
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(CSV_COLUMNS)
        for point in points:
            error = "" if math.isnan(point.standard_error) else repr(point.standard_error)
            writer.writerow(
                [point.panel, point.algorithm, point.env_steps, repr(point.mean), error, point.seeds]
            )


def plot_curves(
    run_dirs: Sequence[str | Path], output: str | Path, *, metric: str = "train", per_body: bool = False
) -> Figure:
    """Learning curves of the runs (see the module docstring) saved as ``output`` (PNG) and its numbers
    as the CSV of the same stem; returns the figure.

    Raises:
        ConfigError: a folder is not a run, has no metrics, or has no ``eval/*`` values for ``metric="eval"``.
    """
    if metric not in METRIC_PREFIXES:
        raise ValueError(f"metric must be one of {', '.join(METRIC_PREFIXES)}, got {metric!r}")
    runs = [read_run_metrics(Path(run_dir), metric) for run_dir in run_dirs]
    points = curve_points(runs, metric, per_body)
    figure = curves_figure(points, metric)
    output = Path(output)
    save(figure, output)
    write_points_csv(points, output.with_suffix(".csv"))
    return figure


# Learning diagnostics


DIAGNOSTIC_ROWS = (
    (("return",), "return (training episodes)"),
    (("length",), "episode length (steps)"),
    (("diag/estimate", "diag/return"), "critics' start estimate (solid)\nagainst discounted return (dashed)"),
    (("diag/twin_gap",), "|Q1 - Q2| at the states acted on"),
    (("diag/saturated",), "share of saturated actions"),
    (("diag/noise",), "exploration noise applied (RMS)"),
    (("diag/update_share",), "share of the updates"),
)
"""Per row of the diagnostics figure: the metrics columns it draws per body (``<column>/<body>``, the
first solid, the second dashed) and its y label (:mod:`swat_jax.td3.diagnostics`)."""


def diagnostics_figure(run: RunMetrics, bodies: Sequence[str]) -> Figure:
    """A row per diagnostic (:data:`DIAGNOSTIC_ROWS`), a column per body of ``bodies``, a line per seed
    in the seed's colour throughout, so a seed stranded on a plateau reads across the rows."""
    seeds = list(dict.fromkeys(int(row["seed"]) for row in run.rows))
    figure = new_figure()
    figure.set_size_inches(PANEL_SIZE[0] * len(bodies), PANEL_SIZE[1] * 0.8 * len(DIAGNOSTIC_ROWS))
    grid = figure.subplots(len(DIAGNOSTIC_ROWS), len(bodies), squeeze=False, sharex=True)
    for row_axes, (columns, label) in zip(grid, DIAGNOSTIC_ROWS, strict=True):
        for axes, body in zip(row_axes, bodies, strict=True):
            by_column = [seed_curves([run], f"{column}/{body}") for column in columns]
            for index, seed in enumerate(seeds):
                for curves, style in zip(by_column, ("-", "--"), strict=False):
                    curve = curves[index]
                    steps = sorted(curve)
                    axes.plot(steps, [curve[step] for step in steps], style, color=f"C{index % 10}",
                              marker="." if len(steps) < 20 else None,
                              label=f"seed {seed}" if style == "-" else None)  # fmt: skip
            axes.set_ylabel(label if body == bodies[0] else "")
    for axes, body in zip(grid[0], bodies, strict=True):
        axes.set_title(body)
    for axes in grid[-1]:
        axes.set_xlabel("environment steps")
    grid[0][-1].legend()
    figure.tight_layout()
    return figure


def plot_diagnostics(run_dir: str | Path, output: str | Path, *, bodies: Sequence[str] = ()) -> Figure:
    """The learning diagnostics of one run (:func:`diagnostics_figure`) saved as ``output`` (PNG), for
    ``bodies`` (names, as the metrics columns have them; default every body of the run).

    Raises:
        ConfigError: the folder is not a run, has no metrics, or has no ``diag/*`` columns.
        ValueError: a body the run did not train.
    """
    run = read_run_metrics(Path(run_dir), "train")
    trained = run.body_labels("train")
    if not any(column.startswith("diag/") for column in run.rows[0]):
        raise ConfigError(
            f"{run_dir}: no diag/* columns in {CSV_FILE}: the run was trained with --iteration.no-diagnostics "
            "or before the diagnostics existed; train it again to see them"
        )
    unknown = [body for body in bodies if body not in trained]
    if unknown:
        raise ValueError(f"{run_dir} did not train {', '.join(unknown)}; its bodies: {', '.join(trained)}")
    figure = diagnostics_figure(run, list(bodies) or trained)
    save(figure, Path(output))
    return figure


# Learned embeddings (Figures 8-11)


def require_embedding(config: TrainConfig, run_dir: Path, module: str) -> None:
    """ValueError, naming the algorithm, if the run's network has no embedding ``module`` (a key of
    :data:`EMBEDDINGS`): SMP has neither, AMORPHEUS and the ablations lack theirs."""
    setting, description, algorithms = EMBEDDINGS[module]
    network = config.network_config()
    if network.architecture != "swat" or not getattr(network, setting):
        raise ValueError(
            f"{run_dir} trained {config.algo}, whose network has no {description}; plot a {algorithms} run"
        )


def embedding_params(policy: TrainedPolicy, seed_index: int, module: str) -> dict:
    """The variables of one embedding module (``traversal_embedding`` or ``relational_embedding``) of a
    seed's actor, ready for that module's ``apply``."""
    return {"params": policy.seed_params(seed_index)["params"]["policy"][module]}


def positional_embeddings(policy: TrainedPolicy, seed_index: int, structure: StructureBatch) -> np.ndarray:
    """[total limbs, width] each real limb's positional embedding (its traversal tables' rows
    concatenated), the bodies' limbs one after another."""
    module = TraversalEmbedding(policy.config.network_config())
    variables = embedding_params(policy, seed_index, "traversal_embedding")
    embeddings = jax.vmap(lambda positions: module.apply(variables, positions))(structure.traversal_positions)
    return np.asarray(embeddings)[structure.limb_mask]


def tsne(points: np.ndarray) -> np.ndarray:
    """[n, 2] t-SNE of ``points`` [n, d] (fixed random state; perplexity below n)."""
    perplexity = min(PERPLEXITY, len(points) - 1)
    return TSNE(n_components=2, perplexity=perplexity, random_state=TSNE_RANDOM_STATE).fit_transform(points)


def embeddings_figure(coordinates: np.ndarray, bodies: Sequence[Morphology], title: str) -> Figure:
    """One scatter per body (its marker) with a point per limb coloured by limb type, the limbs of the
    bodies one after another in ``coordinates`` [total limbs, 2]; a legend of bodies and one of types."""
    types = list(
        dict.fromkeys(body.limb_type_name(limb) for body in bodies for limb in range(body.num_limbs))
    )
    colours = {name: f"C{index % 10}" for index, name in enumerate(types)}
    styles = [BODY_STYLES[index % len(BODY_STYLES)] for index in range(len(bodies))]
    legend_columns = math.ceil(len(bodies) / LEGEND_ROWS)
    figure = new_figure()
    figure.set_size_inches(6 + 3 * legend_columns, 6)
    axes = figure.add_subplot()
    start = 0
    for body, (marker, filled) in zip(bodies, styles, strict=True):
        points = coordinates[start : start + body.num_limbs]
        start += body.num_limbs
        limb_colours = [colours[body.limb_type_name(limb)] for limb in range(body.num_limbs)]
        fill = {"c": limb_colours} if filled else {"facecolors": "none", "edgecolors": limb_colours}
        axes.scatter(points[:, 0], points[:, 1], marker=marker, s=40, **fill)
    body_legend = axes.legend(
        handles=[
            legend_handle(marker, "0.4", body.name, filled)
            for body, (marker, filled) in zip(bodies, styles, strict=True)
        ],
        title="body",
        loc="upper left",
        bbox_to_anchor=(1.02, 1),
        ncol=legend_columns,
        fontsize="small",
    )
    axes.add_artist(body_legend)
    # add_artist clips it to the axes, which would keep it out of the saved figure's bounds
    body_legend.set_clip_on(False)
    axes.legend(
        handles=[legend_handle("o", colours[name], name) for name in types],
        title="limb type",
        loc="upper center",
        bbox_to_anchor=(0.5, -0.02),
        ncol=len(types),
        fontsize="small",
    )
    axes.set_title(title)
    axes.set_xticks([])
    axes.set_yticks([])
    figure.tight_layout()
    return figure


def legend_handle(marker: str, colour: str, label: str, filled: bool = True) -> Line2D:
    """A legend entry showing one marker in one colour (hollow unless ``filled``)."""
    face = colour if filled else "none"
    return Line2D([], [], linestyle="", marker=marker, color=colour, markerfacecolor=face, label=label)


def plot_embeddings(run_dir: str | Path, output: str | Path, *, seed_index: int = 0) -> Figure:
    """Figure 8 for one seed of the run's newest checkpoint, over every train and test body of its set,
    saved as ``output``; returns the figure.

    Raises:
        ValueError: the network has no traversal embedding (ConfigError, CheckpointError: not a usable run).
    """
    run_dir = Path(run_dir)
    policy = load_policy(run_dir)
    require_embedding(policy.config, run_dir, "traversal_embedding")
    environment_set = get_set(policy.config.env)
    bodies = [load(body) for body in environment_set.split("all")]
    embeddings = positional_embeddings(policy, seed_index, policy.task_set(bodies).structure)
    title = (
        f"{policy.config.algo} on {environment_set.name}, seed {policy.seeds[seed_index]}: "
        f"t-SNE of the positional embeddings"
    )
    figure = embeddings_figure(tsne(embeddings), bodies, title)
    save(figure, Path(output))
    return figure


def relation_bias(policy: TrainedPolicy, seed_index: int, structure: StructureBatch) -> np.ndarray:
    """[heads, n, n] the bias g(R) that each head adds to the attention logits between the limbs of the one
    body of ``structure`` (unpadded)."""
    module = RelationalEmbedding(policy.config.network_config())
    variables = embedding_params(policy, seed_index, "relational_embedding")
    return np.asarray(module.apply(variables, structure.relations[0]))


def relations_figure(bias: np.ndarray, limb_names: Sequence[str], title: str) -> Figure:
    """An n x n heatmap per head (rows: the attending limb, columns: the attended limb) with a colour bar each."""
    heads = bias.shape[0]
    figure = new_figure()
    size = 1.6 + 0.45 * len(limb_names)
    figure.set_size_inches(heads * (size + 1.2), size + 0.6)
    for head in range(heads):
        axes = figure.add_subplot(1, heads, head + 1)
        image = axes.imshow(bias[head], cmap="viridis")
        axes.set_xticks(range(len(limb_names)), limb_names, rotation=90)
        axes.set_yticks(range(len(limb_names)), limb_names)
        axes.set_title(f"head {head + 1}")
        axes.set_xlabel("attended limb")
        axes.set_ylabel("attending limb")
        figure.colorbar(image, ax=axes, shrink=0.8)
    figure.suptitle(title)
    figure.tight_layout()
    return figure


def plot_relations(
    run_dir: str | Path, body: str | Path, output: str | Path, *, seed_index: int = 0
) -> Figure:
    """Figures 9-11: the relational bias of every head of one seed's actor on ``body`` (a benchmark name or
    MJCF path), saved as ``output``; returns the figure.

    Raises:
        ValueError: the network has no relational embedding, or the body does not fit the policy
            (MorphologyError, ConfigError, CheckpointError: an unusable body or run).
    """
    run_dir = Path(run_dir)
    policy = load_policy(run_dir)
    require_embedding(policy.config, run_dir, "relational_embedding")
    morphology = load(body)
    bias = relation_bias(policy, seed_index, policy.task_set([morphology]).structure)
    title = (
        f"{policy.config.algo}, seed {policy.seeds[seed_index]}: relational bias g(R) on {morphology.name}"
    )
    figure = relations_figure(bias, morphology.limb_names, title)
    save(figure, Path(output))
    return figure


# Shared


def new_figure() -> Figure:
    """A figure on the off-screen Agg canvas (independent of pyplot and of any display)."""
    figure = Figure(dpi=100)
    FigureCanvasAgg(figure)
    return figure


def save(figure: Figure, path: Path) -> None:
    """Write ``figure`` as a PNG (the folder is created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, format="png", dpi=150, bbox_inches="tight")
    print(f"wrote {path}", file=sys.stderr)


Png = Annotated[Path, tyro.conf.arg(aliases=("-o",))]
"""The ``-o/--output`` PNG of every figure."""


@dataclasses.dataclass(frozen=True)
class CurvesCommand:
    """Return against environment steps (Figures 4-6): the mean over a set's bodies, mean ± standard error
    over seeds as a band, a line per algorithm (runs of one algorithm on one set pool their seeds) and a
    panel per set. The plotted numbers are written beside the PNG as CSV."""

    run_dirs: tyro.conf.Positional[tuple[Path, ...]]
    """Run directories."""
    output: Png
    """The PNG to write."""
    per_body: bool = False
    """Add a panel per body."""
    metric: Metric = "train"
    """train: returns of the training episodes, as the paper plots; eval: the deterministic evaluations of
    runs trained with --eval-interval."""

    def draw(self) -> Figure:
        if not self.run_dirs:
            raise ValueError("give at least one RUN_DIR (a folder written by python -m swat_jax.train)")
        return plot_curves(self.run_dirs, self.output, metric=self.metric, per_body=self.per_body)


@dataclasses.dataclass(frozen=True)
class EmbeddingsCommand:
    """A t-SNE of every limb's traversal-based positional embedding over the run's set's train and test
    bodies (Figure 8): marker by body, colour by limb type."""

    run_dir: tyro.conf.Positional[Path]
    """A run of swat or swat_no_re."""
    output: Png
    """The PNG to write."""
    seed_index: int = 0
    """The K-th seed of a multi-seed run (an index into its seeds)."""

    def draw(self) -> Figure:
        return plot_embeddings(self.run_dir, self.output, seed_index=self.seed_index)


@dataclasses.dataclass(frozen=True)
class RelationsCommand:
    """The learned relational bias g(R) of each attention head on one body (Figures 9-11), as an n x n
    heatmap per head labelled with the limb names."""

    run_dir: tyro.conf.Positional[Path]
    """A run of swat or swat_no_pe."""
    body: str
    """A benchmark body name or an MJCF path."""
    output: Png
    """The PNG to write."""
    seed_index: int = 0
    """The K-th seed of a multi-seed run (an index into its seeds)."""

    def draw(self) -> Figure:
        return plot_relations(self.run_dir, self.body, self.output, seed_index=self.seed_index)


@dataclasses.dataclass(frozen=True)
class DiagnosticsCommand:
    """One run's learning diagnostics, a row per diagnostic and a column per body, a line per seed: the
    training return, the episode length, the critics' estimate of each episode's start against the
    discounted return it got, the twin critics' disagreement, the share of saturated actions, the
    exploration noise applied and each body's share of the updates (docs/training.md, "Diagnostics")."""

    run_dir: tyro.conf.Positional[Path]
    """A run directory (trained with the diagnostics, the default)."""
    output: Png
    """The PNG to write."""
    bodies: tuple[str, ...] = ()
    """Only these bodies (as metrics.csv names them, e.g. hopper_3); default every body of the run."""

    def draw(self) -> Figure:
        return plot_diagnostics(self.run_dir, self.output, bodies=self.bodies)


PlotCommand = (
    Annotated[CurvesCommand, tyro.conf.subcommand("curves")]
    | Annotated[EmbeddingsCommand, tyro.conf.subcommand("embeddings")]
    | Annotated[RelationsCommand, tyro.conf.subcommand("relations")]
    | Annotated[DiagnosticsCommand, tyro.conf.subcommand("diagnostics")]
)
"""``python -m swat_jax.plot curves|embeddings|relations|diagnostics``: the paper's figures and a run's
diagnostics from training runs (PNG; curves also write their numbers as CSV)."""


def run(command: CurvesCommand | EmbeddingsCommand | RelationsCommand | DiagnosticsCommand) -> str | None:
    """Draw and save the figure the command asks for (:func:`save` says where); for curves, returns where
    their numbers were written."""
    command.draw()
    return f"wrote {command.output.with_suffix('.csv')}" if isinstance(command, CurvesCommand) else None


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a bad run directory, body or option)."""
    enable_caches()
    return run_command(
        PlotCommand,
        run,
        argv,
        (CheckpointError, MorphologyError, ValueError, OSError),
        prog="python -m swat_jax.plot",
    )


if __name__ == "__main__":
    sys.exit(main())
