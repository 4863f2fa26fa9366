"""Scoring a drive: the evaluator and its report (:mod:`.evaluate`), the spectrum and rank test
(:mod:`.spectrum`), motion advice (:mod:`.advice`), figures (:mod:`.plots`) and live guidance
as the keyframes come in (:mod:`.live`)."""
