"""Core: errors, validated YAML fields, units, rigid motions, declared noise, output files, console
messages, the compiled-code decorator. Imports nothing of fgcal.
"""
