"""What a run leaves behind, each reading the one evaluated result: the run folder
(summary.json, trace files), the Rerun recording, the PNG figures, and the viewer."""
