"""Where users run the tool: slicer post-processing hooks and print-farm folders."""
