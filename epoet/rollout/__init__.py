"""Running episodes: the ES policy, the batched engine, populations and the backends that
spread them over cores or a Ray cluster (`evaluators.evaluator_for`)."""
