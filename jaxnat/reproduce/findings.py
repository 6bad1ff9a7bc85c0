"""The paper's claims, each in its own words, and the comparisons each makes of the finished
cells; how a comparison and a claim are judged (four outcomes, the learning gate, speed
checkpoints) is `verdicts.py`'s docstring.

Per claim: PPO and ACKTR "close to 1 on MNIST": each cell's interval against 0.9, on the 3-layer
CNN only (the claim is made of the CNN; with ResNet-18 the paper has ACKTR and A2C "suffer
dramatically", PPO alone keeping its MNIST performance). "A2C worst": PPO and ACKTR each above
A2C, per dataset and trunk. "Worse on CIFAR": MNIST above each CIFAR, per algorithm and trunk.
"Fewer steps M" (speed): M=10 above M=20 above M=40 at each speed checkpoint, on the return
normalised between each cell's untrained policy and the best return (their floors differ). "Initially a larger
window, later w=2" (speed): w=5 and w=7 above w=2 at the first checkpoint, w=2 above both at the
last. Localisation: the 3-layer CNN above ResNet-18, per dataset and algorithm (the drop's size,
"small", is not judged). Atari "worst with video": no background and the noise background each
above video, per game and algorithm. PixelMuJoCo "noise as good as pixels" (PPO and A2C, as the
paper names): `verdicts.as_good`, the pixel policy gated. jaxnat's noise control: the real
observation above pure noise. jaxnat's PixelMuJoCo reference: each observation's policy above the
constant-observation policy of the same robot and algorithm (a policy no better than one that
sees nothing learned a state-independent gait: "noise as good as pixels" then says little).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from jaxnat.reproduce.aggregates import MAX_RETURNS
from jaxnat.reproduce.labels import dataset_label
from jaxnat.reproduce.verdicts import (SPEED_CHECKPOINTS, Verdict, as_good, at_least, checkpoint_label,
                                       checkpoint_steps, judge, not_reached, ordered)

__all__ = ["Finding", "Verdict", "FINDINGS", "CLOSE_TO_ONE", "noise_control_pairs"]

CLOSE_TO_ONE = 0.9  # "average reward close to 1": the interval at or above this


@dataclasses.dataclass(frozen=True)
class Finding:
    claim: str  # the paper's words
    experiment: str | tuple[str, ...]  # the --only names whose cells it reads (any one of them)
    rule: Callable  # results -> Verdict

    @property
    def experiments(self) -> tuple[str, ...]:
        return (self.experiment,) if isinstance(self.experiment, str) else self.experiment

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


def _up(result) -> str:
    return result.cell.algo.upper()


def _close_to_one(results) -> Verdict:
    cells = [r for r in _select(results, "classify", "classify-cnn", dataset="mnist")
             if r.cell.algo in ("ppo", "acktr")]
    return judge("PPO/ACKTR with the 3-layer CNN on handwritten digits",
                 [at_least(f"{_up(r)} cnn on {dataset_label(r.cell)}", r, CLOSE_TO_ONE,
                           " (jaxnat's reading of \"close to 1\"; the paper gives no number)") for r in cells])


def _a2c_worst(results) -> Verdict:
    panels: dict = {}
    for r in results:
        if r.cell.experiment == "classify" and _figure_of_classify(r):
            panels.setdefault((r.cell.labels["dataset"], r.cell.labels["trunk"]), {})[r.cell.algo] = r
    comparisons = [ordered(f"{dataset_label(algos['a2c'].cell)} {trunk}", (algo.upper(), r), ("A2C", algos["a2c"]))
                   for (dataset, trunk), algos in panels.items() if "a2c" in algos
                   for algo, r in algos.items() if algo != "a2c"]
    return judge("A2C beside PPO or ACKTR", comparisons)


def _cifar_harder(results) -> Verdict:
    pairs = _pairs(results, lambda r: _figure_of_classify(r) and r.cell.labels.get("dataset") == "mnist",
                   lambda r: _figure_of_classify(r) and r.cell.labels.get("dataset") in ("cifar10", "cifar100"),
                   ("trunk",))
    return judge("handwritten digits beside the CIFAR photos",
                 [ordered(f"{_up(a)} {a.cell.labels['trunk']}", (dataset_label(a.cell), a), (dataset_label(b.cell), b))
                  for a, b in pairs])


def _at_checkpoints(label: str, pairs, parts=None, top: float | None = None) -> list:
    """Each `(high, low)` pair of `(name, result)`s ordered at each speed checkpoint (`parts`: the
    checkpoints' indices to judge it at; `top`: on scores normalised to it, `verdicts.ordered`)."""
    comparisons = []
    for high, low in pairs:
        for i, (checkpoint, step) in enumerate(checkpoint_steps(high[1], low[1])):
            if parts is not None and i not in parts:
                continue
            if step is None:
                comparisons.append(not_reached(f"{label} {high[0]} vs {low[0]}".strip(), checkpoint,
                                               (high[1], low[1])))
            else:
                comparisons.append(ordered(f"{label} {checkpoint_label(checkpoint, step)}".strip(), high, low,
                                           at=step, top=top))
    return comparisons


def _smaller_m_easier(results) -> Verdict:
    cells = sorted(_select(results, "classify", "sweep", w=5), key=lambda r: r.cell.labels["M"])
    named = [(f"M={r.cell.labels['M']}", r) for r in cells]
    # Normalised: the return's floor (-0.1 M) and the untrained policy's return move with M.
    return judge("the M sweep", _at_checkpoints("", list(zip(named, named[1:])), top=MAX_RETURNS["classify"]))


def _small_window_later(results) -> Verdict:
    cells = {r.cell.labels["w"]: r for r in _select(results, "classify", "sweep", M=20)}
    if 2 not in cells or len(cells) < 2:
        return judge("the window sweep")
    small, larger = ("w=2", cells[2]), [(f"w={w}", cells[w]) for w in sorted(cells) if w > 2]
    last = len(SPEED_CHECKPOINTS) - 1
    return judge("the window sweep", _at_checkpoints("initially", [(w, small) for w in larger], parts=(0,)),
                 _at_checkpoints("later", [(small, w) for w in larger], parts=(last,)))


def _resnet_worse_localize(results) -> Verdict:
    pairs = _pairs(results, _is("localize", "localize-cnn"), _is("localize", "localize-resnet18"), ("dataset",))
    return judge("localisation with both trunks",
                 [ordered(f"{dataset_label(a.cell)} {_up(a)}", ("CNN", a), ("ResNet-18", b)) for a, b in pairs])


def _video_lowers_atari(results) -> Verdict:
    comparisons = []
    for background in ("none", "noise"):
        pairs = _pairs(results, _is("atari", background=background), _is("atari", background="video"), ("game",))
        comparisons += [ordered(f"{a.cell.labels['game']} {_up(a)}", (background, a), ("video", b)) for a, b in pairs]
    return judge("Atari with and without video", comparisons)


def _noise_as_good(results) -> Verdict:
    pairs = _pairs(results, _is("mujoco", observation="checker"), _is("mujoco", observation="noise"), ("robot",))
    return judge("PPO/A2C on PixelMuJoCo from pixels and noise",
                 [as_good(f"{a.cell.labels['robot']} {_up(a)}", ("pixels", a), ("noise", b))
                  for a, b in pairs if a.cell.algo in ("ppo", "a2c")])


def _sight_helps(results) -> Verdict:
    comparisons = []
    for observation in ("checker", "video", "noise"):
        pairs = _pairs(results, _is("mujoco", observation=observation), _is("mujoco", observation="constant"),
                       ("robot",))
        comparisons += [ordered(f"{a.cell.labels['robot']} {_up(a)}", (observation, a), ("constant", b),
                                gate_low=True) for a, b in pairs]
    return judge("PixelMuJoCo against the constant-observation reference", comparisons)


def _noise_control(results) -> Verdict:
    return judge("the vision noise control", [ordered(f"{a.cell.experiment} {dataset_label(a.cell)}", ("real", a),
                                                      ("noise", b)) for a, b in noise_control_pairs(results)])


FINDINGS = (
    Finding("PPO and ACKTR are able to achieve average reward close to 1 on MNIST", "classify", _close_to_one),
    Finding("A2C consistently performs worst across all datasets and trunk models", "classify", _a2c_worst),
    Finding("Performance is worse on CIFAR10 and CIFAR100 [than MNIST]", "classify", _cifar_harder),
    Finding("Performance increases with fewer number of steps [M]", "classify", _smaller_m_easier),
    Finding("Initially, a larger window size performs better, [...] as training continues the smaller window w=2 "
            "dominates", "classify", _small_window_later),
    Finding("a small drop in performance when moving from the 3-layer CNN trunk to ResNet-18 [localisation]",
            "localize", _resnet_worse_localize),
    Finding("worst performance with video (Natural) [Atari: below the static black and the noise backgrounds]", "atari",
            _video_lowers_atari),
    Finding("Even in the case where there is no information returned in the observation [...] PPO and A2C are able "
            "to learn as good a policy as when actual state information is provided [PixelMuJoCo, pure noise]",
            "mujoco", _noise_as_good),
    Finding("(not in the paper; jaxnat's reference) what \"as good\" means: each PixelMuJoCo policy (checker, video, "
            "noise) is above the policy that sees a constant observation (the best state-independent action "
            "distribution), their 95% intervals apart", "mujoco", _sight_helps),
    Finding("(not in the paper; jaxnat's control) the vision tasks are not learned from pure noise: the real "
            "observation's policy is above the noise policy, their 95% intervals apart", ("classify", "localize"),
            _noise_control),
)
