"""The ePOET loop: environment-agent pairs, PATA-EC novelty, reproduction and transfer."""
