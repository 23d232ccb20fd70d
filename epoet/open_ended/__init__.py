"""The open-ended loop (environment-agent pairs, PATA-EC novelty, reproduction and transfer) and
ePOET, its instance with OpenAI-ES as each pair's optimiser, which other loops extend. Its
algorithms' family is `Family.OPEN_ENDED`; the word POET alone names Wang et al.'s algorithm
(uber-research/poet), never this package."""
