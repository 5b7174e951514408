"""A campaign's quality thresholds (docs/quality.md): the guide's campaign file loads as it
says, and a threshold that does not exist is refused by name."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from pydantic import ValidationError

from crowdteleop.coord.service.campaign import load_campaigns
from crowdteleop.recording.quality import QualityThresholds

GUIDE = Path(__file__).parents[2] / "docs" / "quality.md"


def test_the_guides_campaign_file_sets_two_thresholds_and_keeps_the_rest(tmp_path):
    block = re.search(r"```yaml\n(.*?)```", GUIDE.read_text(), re.S)
    assert block, "docs/quality.md shows a campaign file"
    path = tmp_path / "campaign.yaml"
    path.write_text(block.group(1))
    [campaign] = load_campaigns(path)
    assert campaign.quality.longest_pause_s == 8 and campaign.quality.path_ratio == 2.5
    assert campaign.quality.setbacks == QualityThresholds().setbacks


def test_an_unknown_threshold_is_refused_by_name(tmp_path):
    path = tmp_path / "campaign.yaml"
    path.write_text("name: x\ntasks: [lift]\nquality: {idle_forever_s: 3}\n")
    with pytest.raises(ValidationError, match="idle_forever_s"):
        load_campaigns(path)
