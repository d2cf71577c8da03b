"""Segmentation (or any scene) -> served model in one command: fem_offline's sweep and cases, then training's fit."""
