"""Bonus files from accepted demonstrations, in the form each study platform takes them
(docs/workers.md):

- Prolific's bulk bonus ("Bulk bonus payment" on a study's submissions, or the API's
  `csv_bonuses`): one line per participant, `<PROLIFIC_PID>,<amount>`, the amount in the
  study's currency with two decimals, no header.
- MTurk: a CSV with the header `WorkerId,AssignmentId,BonusAmount,Reason`, one row per
  worker, each row one `SendBonus` call (which needs the assignment the worker was paid for:
  the `assignmentId` of their link, kept as the worker's `external_session`).

Only workers who came from that platform get lines, only for accepted demonstrations of the
campaign's sessions; a worker with none gets no line. An MTurk worker whose link carried no
assignment id (a preview) cannot be paid a bonus, and is left out.
"""

from __future__ import annotations

import csv
import io
from collections import Counter
from dataclasses import dataclass
from decimal import ROUND_HALF_UP, Decimal
from typing import Literal

from crowdteleop.coord.db.worker_stats import WorkerStatsStore

BonusFormat = Literal["prolific", "mturk"]
MTURK_HEADER = ("WorkerId", "AssignmentId", "BonusAmount", "Reason")
CENT = Decimal("0.01")


@dataclass(frozen=True)
class BonusLine:
    worker_id: str
    external_id: str  # PROLIFIC_PID or MTurk workerId
    assignment_id: str | None
    accepted: int
    amount: Decimal


def money(value: float | str | Decimal) -> Decimal:
    """An amount to the cent (half up), from a float as written (0.1 is ten pence)."""
    return Decimal(str(value)).quantize(CENT, rounding=ROUND_HALF_UP)


async def bonus_lines(
    stats: WorkerStatsStore, campaign: str, platform: BonusFormat, per_accepted: Decimal
) -> list[BonusLine]:
    """Who gets what: `per_accepted` for each accepted demonstration of `campaign`."""
    accepted = Counter(
        e.worker_id for e in await stats.episodes(campaign=campaign) if e.decision == "accepted"
    )
    lines = []
    for worker in await stats.workers(campaign):
        count = accepted[worker.id]
        if worker.source != platform or not worker.external_id or count == 0:
            continue
        if platform == "mturk" and not worker.external_session:
            continue
        lines.append(
            BonusLine(
                worker.id,
                worker.external_id,
                worker.external_session,
                count,
                money(per_accepted * count),
            )
        )
    return lines


def bonus_text(lines: list[BonusLine], platform: BonusFormat, campaign: str) -> str:
    """The file's text for `platform` (module docstring)."""
    if platform == "prolific":
        return "".join(f"{line.external_id},{line.amount}\n" for line in lines)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(MTURK_HEADER)
    for line in lines:
        plural = "s" if line.accepted != 1 else ""
        reason = f"{line.accepted} accepted demonstration{plural} in {campaign}"
        writer.writerow((line.external_id, line.assignment_id, str(line.amount), reason))
    return out.getvalue()


async def bonus_file(
    stats: WorkerStatsStore, campaign: str, platform: BonusFormat, per_accepted: float
) -> str:
    """The bonus file of `campaign` for `platform`."""
    lines = await bonus_lines(stats, campaign, platform, Decimal(str(per_accepted)))
    return bonus_text(lines, platform, campaign)
