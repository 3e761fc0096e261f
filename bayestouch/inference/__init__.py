"""Bayesian inference: priors, likelihoods (contact, raw-current and patch levels), samplers, posterior outputs."""
