"""Experiments run on the product's code, not part of it (not in the wheel): each measures
something the product claims, in lockstep, and reports it."""
