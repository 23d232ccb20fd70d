"""Evolution strategies: the flat numpy policy (`policy`) and the OpenAI-ES optimiser."""
