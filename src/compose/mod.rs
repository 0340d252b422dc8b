//! Compositing: the person over an equirectangular panorama (VR) or as a premultiplied alpha layer (AR).
