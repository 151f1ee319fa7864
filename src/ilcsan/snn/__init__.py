"""The spiking actor family: neuron dynamics, ensemble layers, encoders, intra-layer connections, decoders."""
