"""MSE (RGB in [0, 1]) and GMSD of rendered images against their input, for bench.sh.

GMSD follows the authors' GMSD.m on Octave's rgb2gray luma (0-255), as covec::perceptual::gmsd
does; `metrics.py --check FIXTURES` verifies it against the Octave values that
tests/perceptual_reference.rs holds. Usage: metrics.py REF.png RENDER.png... (one "mse gmsd"
line per render)."""
import sys, numpy as np
from PIL import Image
def flat(p):
    im = Image.open(p).convert("RGBA"); bg = Image.new("RGBA", im.size, (255,255,255,255)); bg.alpha_composite(im)
    return np.asarray(bg.convert("RGB"), dtype=np.float64) / 255
def luma(rgb): return rgb @ np.array([0.298936, 0.587043, 0.114021]) * 255
def conv_same_zero(a, k):
    # MATLAB conv2(a, k, 'same') for a 3x3 kernel
    p = np.pad(a, 1); out = np.zeros_like(a); kf = k[::-1, ::-1]
    for i in range(3):
        for j in range(3):
            out += kf[i, j] * p[i:i+a.shape[0], j:j+a.shape[1]]
    return out
def gmsd(ref, dist):
    out = []
    for y in (luma(ref), luma(dist)):
        p = np.pad(y, ((0,1),(0,1)))
        avg = (p[:-1,:-1] + p[1:,:-1] + p[:-1,1:] + p[1:,1:]) / 4
        y = avg[::2, ::2]
        dx = np.array([[1,0,-1]]*3)/3.0
        gx = conv_same_zero(y, dx); gy = conv_same_zero(y, dx.T)
        out.append(np.sqrt(gx*gx + gy*gy))
    g1, g2 = out; T = 170.0
    q = (2*g1*g2 + T) / (g1*g1 + g2*g2 + T)
    return q.std(ddof=1)
if __name__ == "__main__":
    if sys.argv[1] == "--check":
        d = sys.argv[2]
        g = gmsd(flat(f"{d}/hopper_ref.png"), flat(f"{d}/hopper_vector.png"))
        assert abs(g - 0.2404116720) < 1e-6, g
        sys.exit(0)
    ref = flat(sys.argv[1])
    for png in sys.argv[2:]:
        d = flat(png)
        print(f"{((d-ref)**2).mean():.6f} {gmsd(ref, d):.6f}")
