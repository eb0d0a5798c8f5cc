"""Diagnosis of a fixed camera's history: which effect breaks the linear model, where, and what modelling it changes."""
