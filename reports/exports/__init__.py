"""Exports of dgcal results in the files and conventions of mapping software."""
