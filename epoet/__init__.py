"""epoet: open-ended locomotion learning."""
