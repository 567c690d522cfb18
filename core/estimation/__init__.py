"""Estimation math several estimators share: the paper's model, its batch fit, the sample guard."""
