"""Helpers every part of hdrive shares and none owns: argument checks, the markdown table writer, the plot style,
and output folders written atomically."""
