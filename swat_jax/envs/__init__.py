"""Benchmark environments on MuJoCo MJX: observations, rewards, terminations, many bodies in one step."""
