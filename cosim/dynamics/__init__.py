"""The blocks' nominal rigid-body models (the plant's own are the FMU's C): the planar chain
and the spatial chain of a URDF, two model types behind the same calls (:mod:`.model`)."""
