"""Evolution strategies: the OpenAI-ES optimiser and observation normalisation."""
