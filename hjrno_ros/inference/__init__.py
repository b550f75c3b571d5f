"""Running a card's network without torch (onnxruntime): what the node loads when its card lists an ONNX file."""
