"""How a reproduction judges the paper's claims (`findings.FINDINGS`): each claim makes one or
more comparisons of finished cells, each comparison has one outcome, and the claim's verdict
aggregates them.

**The quantity compared** is a cell's training return, as the paper's figures plot: each seed's
mean over the last 10% of its updates in which an episode ended, the mean over seeds with a 95%
percentile-bootstrap interval (`report.CellResult.final_train`). Claims about learning speed
read it at fixed env-step checkpoints instead (`SPEED_CHECKPOINTS`; `CellResult.train_at`).
Cells whose returns are on different scales (the classification sweep over M: a wrong guess
costs 0.1 a step, so the floor is -0.1 M and the untrained policy's return moves with M) are
compared on the return normalised per seed between the cell's untrained policy (0) and the
task's best return (1), as the report's aggregates are (`normalised`).

**Outcomes of a comparison** (the paper puts cell `high` above cell `low`):

- *reproduced*: the two 95% intervals are apart, in the paper's order (`high.low > low.high`);
- *contradicted*: the intervals are apart, in the reverse order;
- *inconclusive*: the intervals overlap;
- *not shown*: the cell whose learning the comparison presupposes did not learn, whatever the
  intervals say. That cell is `high`, the one the paper says does better (it must have learned
  something to be better at it); `low` need not learn, as the paper's own claims include
  policies that "fail completely" (Atari with video), and the noise control's noise cell is
  meant not to learn. Claims of one cell against a number gate that cell. A `low` cell that is a
  reference, not a policy the paper describes, is gated too (`ordered(..., gate_low=True)`):
  PixelMuJoCo's constant-observation cell stands for the best state-independent policy, which a
  constant cell that did not learn is not.

Two claims are not orderings. Against a number ("close to 1": `at_least`): reproduced when the
interval is at or above it, contradicted when below, inconclusive when across it. Of equality
("as good a policy": `as_good`, the paper's own test of open loop): reproduced when the other
policy's mean is at or above the lower bound of the reference's interval, contradicted when the
intervals are apart with the other below, else inconclusive; the reference is gated.

**Learning** is judged against the untrained policy of the same cell: a cell learned when its
compared return (final, or at the checkpoint) is above the 95% interval of its untrained
policy's return. The untrained policy's return is its *sampled* return on the *test* split at
update 0 (`eval.jsonl`'s rows with `update` 0, `CellResult.untrained`), the only record of it:
nothing is played on the training split before the first update, and the first update's
training rows hold only the episodes that ended inside its rollout (none where an episode is
longer than a rollout, as in PixelMuJoCo and Atari). Sampled, because the training returns are
sampled; the splits differ only in their images or videos, which an untrained policy cannot
exploit. The uniform random policy (`summary.json`'s `chance`) is another policy and is not
used. Host runs (Natural Atari) evaluate only at the end and record no untrained policy: their
comparisons are *not shown* until the host backend evaluates update 0.

**A claim's verdict**: *contradicted* if any counted comparison is contradicted; *reproduced* if
every counted comparison is reproduced; else *inconclusive*. *Not shown* comparisons are listed
with why and counted neither for nor against, except that a claim whose comparisons are all not
shown is *not shown*; so is a claim in parts ("initially ..., later ...") one part of which is
all not shown, unless another part contradicts it. A claim without its cells is *not run*.

**Speed checkpoints**: a claim about learning speed is judged at `SPEED_CHECKPOINTS` (1M and
10M env steps per seed). A run shorter than a checkpoint is judged at its last step (the table
says at which); a checkpoint that falls at the same step as the one before it is *not reached*
(not shown): a short run gives no later point to compare with.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxnat.reproduce.stats import Interval, bootstrap_ci

__all__ = ["OUTCOMES", "SPEED_CHECKPOINTS", "Comparison", "Verdict", "judge", "not_run", "ordered", "normalised",
           "at_least", "as_good", "checkpoint_steps", "learned"]

OUTCOMES = ("reproduced", "contradicted", "inconclusive", "not shown", "not run")
SPEED_CHECKPOINTS = (1_000_000, 10_000_000)  # env steps per seed: early in training, and the paper's budget


@dataclasses.dataclass(frozen=True)
class Comparison:
    outcome: str  # one of OUTCOMES[:4]
    text: str  # what was compared, its numbers, and why when not shown
    cells: tuple = ()  # the results it read


@dataclasses.dataclass(frozen=True)
class Verdict:
    verdict: str  # one of OUTCOMES
    numbers: str
    cells: tuple = ()  # the results the verdict read (for the share of the paper's budget)

    @property
    def share(self) -> tuple[float, float] | None:
        """The least and the most of the paper's env-step budget that the verdict's cells trained."""
        shares = [r.budget_share for r in self.cells]
        return (min(shares), max(shares)) if shares else None


def _value(result, at: float | None):
    return result.final_train if at is None else result.train_at(at)


def learned(result, at: float | None = None) -> str | None:
    """None when `result`'s return (final, or at env step `at`) is above its untrained policy's
    95% interval; else why it is not shown to have learned."""
    got, untrained = _value(result, at), result.untrained
    if untrained is None:
        return f"{result.cell.name} records no untrained policy (no evaluation at update 0)"
    if not np.isfinite(got.mean):
        return f"{result.cell.name} has no training return"
    if got.mean > untrained.high:
        return None
    return f"{result.cell.name} did not learn: {got} not above its untrained policy's {untrained}"


def _compare(label: str, text: str, gates, cells, outcome) -> Comparison:
    """`outcome()` unless a cell of `gates` (`(cell, env step)` pairs: the cells that must have
    learned, and at which step) did not learn."""
    at = gates[0][1]
    why = next((why for why in (learned(*gate) for gate in gates) if why is not None), None)
    if why is None and not all(np.isfinite(_value(r, at).mean) for r in cells):
        why = "a cell has no training return"
    if why is not None:
        return Comparison("not shown", f"{label}: {text} (not shown: {why})", tuple(cells))
    result = outcome()
    return Comparison(result, f"{label}: {text} ({result})", tuple(cells))


def ordered(label: str, high: tuple, low: tuple, at: float | None = None, top: float | None = None,
            gate_low: bool = False) -> Comparison:
    """The paper puts `high` above `low`; each is `(name, result)`. `at`: judged at this env step.
    `top` (the task's best return): compare the scores normalised between each cell's untrained
    policy (0) and `top` (1), for cells whose returns are on different scales (`normalised`).
    `gate_low`: `low` is a reference that must have learned too."""
    (hn, hr), (ln, lr) = high, low
    if top is not None:
        missing = next((r for r in (hr, lr) if r.untrained is None), None)
        if missing is not None:
            return Comparison("not shown", f"{label}: {hn} vs {ln} (not shown: {missing.cell.name} records no "
                                           "untrained policy, which the normalised score needs)", (hr, lr))
        top_already = next((r for r in (hr, lr) if not r.untrained.mean < top), None)
        if top_already is not None:
            return Comparison("not shown", f"{label}: {hn} vs {ln} (not shown: {top_already.cell.name}'s untrained "
                                           f"policy is at the best return {top:g}: nothing to normalise)", (hr, lr))
    h, lo = (_value(r, at) if top is None else normalised(r, top, at) for r in (hr, lr))

    def outcome():
        return "reproduced" if h.low > lo.high else "contradicted" if lo.low > h.high else "inconclusive"

    scale = "" if top is None else f" (normalised: untrained policy = 0, best return {top:g} = 1)"
    gates = ((hr, at), (lr, at)) if gate_low else ((hr, at),)
    return _compare(label, f"{hn} {h} vs {ln} {lo}{scale}", gates, (hr, lr), outcome)


def normalised(result, top: float, at: float | None = None) -> Interval:
    """The cell's training return (final, or at env step `at`) normalised per seed between its
    untrained policy's mean (0) and `top` (1), with its 95% bootstrap interval over seeds."""
    untrained = result.untrained.mean
    return bootstrap_ci((result.train_per_seed(at) - untrained) / (top - untrained))


def at_least(label: str, result, threshold: float, reading: str = "") -> Comparison:
    """The paper puts `result` at or above `threshold`: its interval above, below, or across it.
    `reading`: where the number comes from, when the paper gives none (shown after it)."""
    got = result.final_train

    def outcome():
        return "reproduced" if got.low >= threshold else "contradicted" if got.high < threshold else "inconclusive"

    return _compare(label, f"{got} vs {threshold:g}{reading}", ((result, None),), (result,), outcome)


def as_good(label: str, reference: tuple, other: tuple) -> Comparison:
    """The paper says `other` learns as good a policy as `reference` (`(name, result)` each):
    reproduced when `other`'s mean is at or above the lower bound of `reference`'s interval,
    contradicted when the intervals are apart with `other` below, else inconclusive."""
    (rn, rr), (on, orr) = reference, other
    ref, got = rr.final_train, orr.final_train

    def outcome():
        return "reproduced" if got.mean >= ref.low else "contradicted" if got.high < ref.low else "inconclusive"

    return _compare(label, f"{rn} {ref} vs {on} {got}", ((rr, None),), (rr, orr), outcome)


def checkpoint_steps(*results) -> list[tuple[int, float | None]]:
    """`(checkpoint, env step judged at)` for each of `SPEED_CHECKPOINTS`: the checkpoint, or the
    last step all `results` reached when they stopped before it; None when that step is the
    previous checkpoint's (not reached)."""
    reached = min((float(r.steps.max()) if r.steps.size else 0.0) for r in results)
    steps, previous = [], None
    for checkpoint in SPEED_CHECKPOINTS:
        step = min(float(checkpoint), reached)
        steps.append((checkpoint, None if step == previous else step))
        previous = step
    return steps


def checkpoint_label(checkpoint: int, step: float) -> str:
    return f"at {checkpoint / 1e6:g}M env steps" + ("" if step == checkpoint else f" (the runs end at {step:,.0f})")


def not_reached(label: str, checkpoint: int, cells) -> Comparison:
    reached = min((float(r.steps.max()) if r.steps.size else 0.0) for r in cells)
    return Comparison("not shown", f"{label} at {checkpoint / 1e6:g}M env steps: not reached (the runs end at "
                                   f"{reached:,.0f}, where an earlier checkpoint was judged)", tuple(cells))


def not_run(what: str) -> Verdict:
    return Verdict("not run", f"no finished cells for {what}")


def judge(what: str, *parts: list[Comparison]) -> Verdict:
    """The claim's verdict from its comparisons, in `parts` (most claims have one; "initially ...,
    later ..." has two); `what`: the cells it needs, for "not run"."""
    comparisons = [c for part in parts for c in part]
    if not comparisons:
        return not_run(what)
    counted = [c.outcome for c in comparisons if c.outcome != "not shown"]
    if "contradicted" in counted:
        verdict = "contradicted"
    elif any(all(c.outcome == "not shown" for c in part) for part in parts):
        verdict = "not shown"
    elif all(c == "reproduced" for c in counted):
        verdict = "reproduced"
    else:
        verdict = "inconclusive"
    tally = ", ".join(f"{sum(c.outcome == o for c in comparisons)} {o}" for o in OUTCOMES[:4]
                      if any(c.outcome == o for c in comparisons))
    cells = tuple({id(r): r for c in comparisons for r in c.cells}.values())
    count = f"{len(comparisons)} comparison{'s' * (len(comparisons) > 1)}"
    return Verdict(verdict, f"{count}: {tally}. " + "; ".join(c.text for c in comparisons), cells)
