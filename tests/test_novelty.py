"""PATA-EC and novelty on constructed score matrices."""

import numpy as np
import pytest

from epoet.open_ended.novelty import novelties, novelty, pata_ec, rank_by_novelty

LOW, HIGH = 500.0, 3000.0


def test_pata_ec_clips_then_ranks():
    # clipped to [500, 2000, 3000, 1500] -> ranks [0, 2, 3, 1] -> /3 - 0.5
    ec = pata_ec(np.array([100.0, 2000.0, 5000.0, 1500.0]), LOW, HIGH)
    np.testing.assert_allclose(ec, np.array([0, 2, 3, 1]) / 3 - 0.5)


def test_pata_ec_ties_from_clipping_share_their_average_rank():
    np.testing.assert_array_equal(pata_ec(np.array([-10.0, 0.0, 400.0]), LOW, HIGH), [0, 0, 0])
    # 4000 and 3500 both clip to 3000: ranks [0, 1.5, 1.5] -> [-0.5, 0.25, 0.25]
    np.testing.assert_allclose(
        pata_ec(np.array([1000.0, 4000.0, 3500.0]), LOW, HIGH), [-0.5, 0.25, 0.25]
    )


def test_pata_ec_single_agent_is_zero_not_nan():
    np.testing.assert_array_equal(pata_ec(np.array([1234.0]), LOW, HIGH), [0.0])
    np.testing.assert_array_equal(pata_ec(np.array([[1.0], [5000.0]]), LOW, HIGH), [[0.0], [0.0]])


def test_pata_ec_of_a_matrix_is_row_by_row():
    scores = np.array([[600.0, 2500.0, 900.0], [3000.0, 100.0, 2000.0]])
    ec = pata_ec(scores, LOW, HIGH)
    for row, expected in zip(scores, ec):
        np.testing.assert_array_equal(pata_ec(row, LOW, HIGH), expected)


def test_novelty_is_mean_distance_to_k_nearest():
    archive = np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0], [0.0, 1.0]])
    candidate = np.array([0.0, 0.0])
    # distances [0, 5, 10, 1]: k=2 -> (0 + 1)/2, k=3 -> (0 + 1 + 5)/3
    assert novelty(candidate, archive, k=2) == pytest.approx(0.5)
    assert novelty(candidate, archive, k=3) == pytest.approx(2.0)
    assert novelty(candidate, archive, k=10) == pytest.approx(4.0)  # m < k: all m


def test_novelty_with_one_environment_and_with_none():
    assert novelty(np.array([0.5, -0.5]), np.array([[-0.5, 0.5]]), k=5) == pytest.approx(np.sqrt(2))
    assert novelty(np.array([0.5, -0.5]), np.empty((0, 2)), k=5) == np.inf
    assert novelty(np.array([0.5, -0.5]), [], k=5) == np.inf


def test_single_agent_pipeline_has_no_nan():
    archive = pata_ec(np.array([[700.0], [2900.0]]), LOW, HIGH)
    candidate = pata_ec(np.array([100.0]), LOW, HIGH)
    assert novelty(candidate, archive, k=5) == 0.0
    order, values = rank_by_novelty(candidate[None, :], archive, k=5)
    assert order.tolist() == [0] and not np.isnan(values).any()


def test_rank_by_novelty_puts_the_odd_candidate_first():
    # five agents; existing environments all rank agent 0 worst and agent 4 best
    existing = np.array(
        [
            [100.0, 800.0, 1200.0, 1800.0, 2600.0],
            [200.0, 900.0, 1100.0, 2000.0, 2900.0],
            [300.0, 700.0, 1300.0, 1900.0, 2700.0],
        ]
    )
    candidates = np.array(
        [
            [150.0, 850.0, 1250.0, 1850.0, 2650.0],  # same ordering
            [2900.0, 1900.0, 1200.0, 800.0, 100.0],  # reversed: the novel one
            [100.0, 900.0, 1300.0, 2900.0, 1900.0],
        ]
    )  # one swap
    order, values = rank_by_novelty(
        pata_ec(candidates, LOW, HIGH), pata_ec(existing, LOW, HIGH), k=5
    )
    assert order.tolist() == [1, 2, 0]
    assert values[0] == pytest.approx(0.0) and values[1] > values[2] > 0


def test_rank_by_novelty_with_empty_archive_keeps_proposal_order():
    order, values = rank_by_novelty(np.zeros((3, 4)), np.empty((0, 4)), k=5)
    assert order.tolist() == [0, 1, 2]
    assert np.all(values == np.inf)
    np.testing.assert_array_equal(novelties(np.zeros((3, 4)), np.empty((0, 4)), k=5), values)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: pata_ec(np.array([1.0, np.nan]), LOW, HIGH), "NaN"),
        (lambda: pata_ec(np.array([]), LOW, HIGH), "n_agents >= 1"),
        (lambda: novelty(np.zeros(3), np.zeros((2, 4)), k=5), "match"),
        (lambda: novelty(np.zeros(3), np.zeros((2, 3)), k=0), "k must be"),
        (lambda: rank_by_novelty(np.zeros(3), np.zeros((2, 3)), k=5), "candidates"),
    ],
)
def test_bad_input_raises_clear_value_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()
