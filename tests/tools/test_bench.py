"""The codec comparison of ``dem-ros bench record`` runs and compares like with like (no timing asserted)."""

from dem_ros.tools.bench import codec_comparison


def test_codec_comparison_covers_every_codec_on_identical_messages():
    c = codec_comparison(n_cdr=20, n_bag=200)  # (it asserts our bytes equal cyclonedds' and every message reads back)
    assert set(c["cdr"]) == {"dem_ros fastcdr", "cyclonedds IdlStruct", "rosbags typestore"}
    assert set(c["mcap"]) == {"dem_ros bag", "mcap package"}
    for figures in (*c["cdr"].values(), *c["mcap"].values()):
        assert all(v > 0 for v in figures.values()), figures
