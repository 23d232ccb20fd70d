"""Everything around a trained agent: its files, the evaluation suite, evaluation, videos and
the terrain gallery (each a `python -m epoet.eval.<command>`)."""
