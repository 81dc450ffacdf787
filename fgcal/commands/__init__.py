"""The fgcal command: the dispatcher (cli), the options the commands share, and one module per
command (its parser and its handler).
"""
