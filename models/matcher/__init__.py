"""Feature matching for loop/revisit verification: XFeat (ONNX) or ORB, mutual NN, PnP-RANSAC gate."""
