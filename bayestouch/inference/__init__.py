"""Bayesian inference: priors, likelihoods (contact level; raw-current level to come), samplers."""
