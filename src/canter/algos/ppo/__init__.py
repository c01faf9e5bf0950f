"""Proximal Policy Optimization: pure loss, pure update, and the jitted iteration."""
