"""Export of the learned matcher to a deployable bundle (``xvmatch export``): ONNX graphs of the
matcher and the appearance network with a manifest, checked by a parity gate
(:mod:`~xvmatch.export.onnx_export`), and the optional static INT8 appearance network
(:mod:`~xvmatch.export.int8`)."""
