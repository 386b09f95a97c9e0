"""Export of the learned matcher to a deployable bundle (``xvmatch export``): the ONNX graphs of
the matcher and the appearance network with their manifest (:mod:`~xvmatch.export.onnx_export`),
the parity gate against the torch modules (:mod:`~xvmatch.export.parity`), the backbone record
and licence notice (:mod:`~xvmatch.export.licence_notice`), the optional static INT8
appearance network (:mod:`~xvmatch.export.int8`), and an appearance network from ``xvmatch
train`` paired with a trained matcher (:mod:`~xvmatch.export.appearance_pairing`)."""
