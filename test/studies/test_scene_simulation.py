"""``hjrno simulate --scenes product``: the product scenes without ROS (the numpy filter on solved tables); the same
scenes over DDS are test/ros/harness/test_product_scenes.py."""

from hjrno_ros.core import safety_filter
from hjrno_ros.studies import product_scenes

CAR_SCENES = product_scenes.ROBOTS["car"][1]
DIFF_DRIVE_SCENES = product_scenes.ROBOTS["diff_drive"][1]


def test_hjrno_simulate_runs_the_scenes(tmp_path):
    """``hjrno simulate --scenes product``: the scenes without ROS (the numpy filter on solved tables) into
    scenes.md; the car passes every scene in every filter mode, the differential drive in the node's
    least-restrictive mode (the older modes cannot leave the margin at rest)."""
    from hjrno_ros import cli

    assert cli.main(["simulate", "--scenes", "product", "--out", str(tmp_path)]) == 0
    car, diff = (tmp_path / "scenes.md").read_text().split("# Product scenes")[1:]

    def rows(text: str) -> list[str]:
        return [line for line in text.splitlines() if line.startswith("| ") and not line.startswith(("| scene",
                                                                                                      "| ---"))]

    assert len(rows(car)) == len(CAR_SCENES) * len(safety_filter.MODES) and all("| none |" in r for r in rows(car))
    judged = [r for r in rows(diff) if "| least_restrictive |" in r]
    assert len(judged) == len(DIFF_DRIVE_SCENES) and all("| none |" in r for r in judged), judged
