"""UAV detection (§4.2): synthetic dataset, detector network and training (torch, development
only), ONNX export, and the onnxruntime runtime (:mod:`.detector`, numpy/OpenCV only)."""
