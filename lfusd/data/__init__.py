"""Reading and writing datasets: raw passes, the Dataset reader, file formats, exports, PyTorch."""
