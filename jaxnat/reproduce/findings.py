"""The paper's claims, each in its own words, and how a reproduction judges it.

A claim is judged on the finished cells it needs, by their final training returns (the
paper's figures plot training returns; `report.CellResult.final_train`): "reproduced" when
it holds in every comparison it makes, "not reproduced" when one fails (the numbers say which),
"not run" when its cells are missing. An ordering ("worst", "harder", "lower") is judged by the
means over seeds, and called "reproduced by the means only" when the two 95% intervals overlap; the one claim of equality ("as good a policy") by the interval: the noise
policy's mean at or above the lower bound of the pixel policy's 95% interval, judged only
where the pixel policy beat the uniform random policy ("not shown" otherwise: two policies that
learned nothing are equal without saying anything about open loop).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

__all__ = ["Finding", "Verdict", "FINDINGS", "noise_control_pairs"]


@dataclasses.dataclass(frozen=True)
class Verdict:
    verdict: str  # "reproduced", "not reproduced", "not run", "not shown (...)"
    numbers: str


@dataclasses.dataclass(frozen=True)
class Finding:
    claim: str  # the paper's words
    experiment: str  # the --only name whose cells it needs
    rule: Callable  # results -> Verdict

    def judge(self, results) -> Verdict:
        return self.rule(results)


def _is(experiment: str, figure: str | None = None, **labels):
    """A predicate on results: this experiment (and figure), with these labels."""
    return lambda r: (r.cell.experiment == experiment and (figure is None or r.cell.figure == figure)
                      and all(r.cell.labels.get(k) == v for k, v in labels.items()))


def _select(results, experiment: str, figure: str | None = None, **labels):
    return [r for r in results if _is(experiment, figure, **labels)(r)]


def _pairs(results, base, other, same: tuple[str, ...]) -> list:
    """`(b, o)` for each result `b` with `base(b)` and `o` with `other(o)` of the same experiment
    and algorithm whose labels `same` agree: the two settings a claim compares."""
    return [(b, o) for b in results if base(b) for o in results
            if other(o) and (o.cell.experiment, o.cell.algo) == (b.cell.experiment, b.cell.algo)
            and all(o.cell.labels.get(k) == b.cell.labels.get(k) for k in same)]


def _figure_of_classify(r) -> bool:
    return r.cell.figure.startswith("classify-")


def noise_control_pairs(results) -> list:
    """`(real, noise)`: each vision noise-control result with its real-observation counterpart
    (same experiment, dataset and algorithm, the 3-layer CNN)."""
    return _pairs(results, lambda r: r.cell.figure != "noise-control" and r.cell.labels.get("trunk") == "cnn",
                  lambda r: r.cell.figure == "noise-control", ("dataset",))


def _fmt(interval) -> str:
    """The mean and its 95% interval: an ordering of means inside each other's intervals is weak."""
    return str(interval)


def _not_run(what: str) -> Verdict:
    return Verdict("not run", f"no finished cells for {what}")


def _verdict(held: int, total: int, numbers: list[str], overlapping: int = 0) -> Verdict:
    """`overlapping`: of the held orderings, how many have overlapping intervals (weak evidence)."""
    word = "reproduced" if held == total else "not reproduced"
    if held == total and overlapping:
        word = "reproduced by the means only (intervals overlap)"
    return Verdict(word, f"{held} of {total}: " + "; ".join(numbers))


def _below(low, high) -> tuple[bool, bool]:
    """(low's mean below high's, and their intervals apart)."""
    return low.mean < high.mean, low.high < high.low


def _ordered(pairs, numbers) -> Verdict:
    """Pairs `(better, worse)` of results: the claim is that each `worse` is below its `better`."""
    checks = [_below(worse.final_train, better.final_train) for better, worse in pairs]
    held = sum(below for below, _ in checks)
    return _verdict(held, len(pairs), numbers, sum(below and not apart for below, apart in checks))


def _close_to_one(results) -> Verdict:
    cells = [r for r in _select(results, "classify", dataset="mnist") if r.cell.algo in ("ppo", "acktr")
             and r.cell.figure.startswith("classify-")]
    if not cells:
        return _not_run("PPO/ACKTR on MNIST")
    numbers = [f"{r.cell.algo.upper()} {r.cell.labels['trunk']} {_fmt(r.final_train)}" for r in cells]
    return _verdict(sum(r.final_train.mean >= 0.9 for r in cells), len(cells), numbers + ["(close to 1: >= 0.9)"])


def _a2c_worst(results) -> Verdict:
    panels: dict = {}
    for r in results:
        if r.cell.experiment == "classify" and _figure_of_classify(r):
            panels.setdefault((r.cell.labels["dataset"], r.cell.labels["trunk"]), {})[r.cell.algo] = r
    panels = {k: v for k, v in panels.items() if "a2c" in v and len(v) >= 2}
    if not panels:
        return _not_run("A2C beside PPO or ACKTR")
    pairs, numbers = [], []
    for (dataset, trunk), algos in panels.items():
        lowest = min((r for algo, r in algos.items() if algo != "a2c"), key=lambda r: r.final_train.mean)
        pairs.append((lowest, algos["a2c"]))
        numbers.append(f"{dataset} {trunk}: A2C {_fmt(algos['a2c'].final_train)} vs the next lowest "
                       f"{lowest.cell.algo.upper()} {_fmt(lowest.final_train)}")
    return _ordered(pairs, numbers)


def _cifar_harder(results) -> Verdict:
    pairs = _pairs(results, lambda r: _figure_of_classify(r) and r.cell.labels.get("dataset") == "mnist",
                   lambda r: _figure_of_classify(r) and r.cell.labels.get("dataset") in ("cifar10", "cifar100"),
                   ("trunk",))
    if not pairs:
        return _not_run("MNIST beside CIFAR")
    numbers = [f"{a.cell.algo.upper()} {a.cell.labels['trunk']}: MNIST {_fmt(a.final_train)} vs "
               f"{b.cell.labels['dataset']} {_fmt(b.final_train)}" for a, b in pairs]
    return _ordered(pairs, numbers)


def _smaller_m_easier(results) -> Verdict:
    cells = sorted([r for r in _select(results, "classify", "sweep", w=5)], key=lambda r: r.cell.labels["M"])
    if len(cells) < 2:
        return _not_run("the M sweep")
    means = [r.final_train.mean for r in cells]
    numbers = [f"M={r.cell.labels['M']} {_fmt(r.final_train)}" for r in cells]
    pairs = len(cells) - 1
    return _verdict(sum(a > b for a, b in zip(means, means[1:])), pairs, numbers)


def _small_window_later(results) -> Verdict:
    cells = {r.cell.labels["w"]: r for r in _select(results, "classify", "sweep", M=20)}
    if 2 not in cells or len(cells) < 2:
        return _not_run("the window sweep")
    larger = [w for w in cells if w > 2]
    early = all(cells[w].early_train().mean > cells[2].early_train().mean for w in larger)
    late = all(cells[2].final_train.mean >= cells[w].final_train.mean for w in larger)
    numbers = [f"w={w}: first 20% {cells[w].early_train().mean:.3g}, final {_fmt(cells[w].final_train)}"
               for w in sorted(cells)]
    return _verdict(int(early) + int(late), 2, numbers)


def _resnet_worse_localize(results) -> Verdict:
    pairs = _pairs(results, _is("localize", "localize-cnn"), _is("localize", "localize-resnet18"), ("dataset",))
    if not pairs:
        return _not_run("localisation with both trunks")
    numbers = [f"{a.cell.labels['dataset']} {a.cell.algo.upper()}: CNN {_fmt(a.final_train)} vs ResNet-18 "
               f"{_fmt(b.final_train)}" for a, b in pairs]
    return _ordered(pairs, numbers)


def _video_lowers_atari(results) -> Verdict:
    pairs = _pairs(results, _is("atari", background="none"), _is("atari", background="video"), ("game",))
    if not pairs:
        return _not_run("Atari with and without video")
    numbers = [f"{a.cell.labels['game']} {a.cell.algo.upper()}: none {_fmt(a.final_train)} vs video "
               f"{_fmt(b.final_train)}" for a, b in pairs]
    return _ordered(pairs, numbers)


def _learned(result) -> bool:
    """Whether the policy's final training return is above the uniform random policy's (or no
    random-policy figure was recorded)."""
    return result.chance is None or result.final_train.mean > result.chance


def _noise_as_good(results) -> Verdict:
    pairs = _pairs(results, _is("mujoco", observation="checker"), _is("mujoco", observation="noise"), ("robot",))
    if not pairs:
        return _not_run("PixelMuJoCo from pixels and from noise")
    untrained = [f"{a.cell.labels['robot']} {a.cell.algo.upper()}: pixels {a.final_train} vs the random policy "
                 f"{a.chance:.4g}" for a, _ in pairs if not _learned(a)]
    pairs = [(a, b) for a, b in pairs if _learned(a)]
    if not pairs:  # two policies that learned nothing are equal without saying anything of open loop
        return Verdict("not shown (the pixel policy did not beat the random policy)", "; ".join(untrained))
    held = [b.final_train.mean >= a.final_train.low for a, b in pairs]
    numbers = [f"{a.cell.labels['robot']} {a.cell.algo.upper()}: pixels {a.final_train} vs noise {_fmt(b.final_train)}"
               f" ({'within or above' if ok else 'below'} the pixels' CI)" for (a, b), ok in zip(pairs, held)]
    return _verdict(sum(held), len(pairs), numbers + [f"not judged, {u}" for u in untrained])


def _noise_control(results) -> Verdict:
    pairs = noise_control_pairs(results)
    if not pairs:
        return _not_run("the vision noise control")
    held = [b.final_train.mean < a.final_train.low for a, b in pairs]
    numbers = [f"{a.cell.experiment} {a.cell.labels['dataset']}: real {a.final_train} vs noise {_fmt(b.final_train)}"
               for a, b in pairs]
    return _verdict(sum(held), len(pairs), numbers)


FINDINGS = (
    Finding("PPO and ACKTR are able to achieve average reward close to 1 on MNIST", "classify", _close_to_one),
    Finding("A2C consistently performs worst across all datasets and trunk models", "classify", _a2c_worst),
    Finding("Performance is worse on CIFAR10 and CIFAR100 [than MNIST]", "classify", _cifar_harder),
    Finding("Performance increases with fewer number of steps [M]", "classify", _smaller_m_easier),
    Finding("Initially, a larger window size performs better, [...] as training continues the smaller window w=2 "
            "dominates", "classify", _small_window_later),
    Finding("a small drop in performance when moving from the 3-layer CNN trunk to ResNet-18 [localisation]",
            "localize", _resnet_worse_localize),
    Finding("worst performance with video (Natural) [Atari: natural video backgrounds lower the scores]", "atari",
            _video_lowers_atari),
    Finding("Even in the case where there is no information returned in the observation [...] PPO and A2C are able "
            "to learn as good a policy as when actual state information is provided [PixelMuJoCo, pure noise]",
            "mujoco", _noise_as_good),
    Finding("(not in the paper; jaxnat's control) the vision tasks are not learned from pure noise: the real "
            "observation's policy beats the noise policy beyond its 95% interval", "classify", _noise_control),
)
