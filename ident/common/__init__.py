"""Helpers every part of hdrive shares and none owns: argument checks, the markdown table writer, the plot style,
output folders written atomically, temporary folders a process owns (removed by the next process when it was
killed), and the one-BLAS-thread limit its computations run under."""
