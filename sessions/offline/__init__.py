"""Offline tools over recorded streams: compensate, replay, and the one metrics module."""
