#!/usr/bin/env python3
# A large hall of big flat polygons (floor, walls, ceiling, columns, table: 2 triangles a face)
# with 24 chairs of small triangles and one dense torus on the table: few large axis-aligned
# triangles spanning many cells beside small detailed objects (docs/EXPERIMENTS.md, "Interiors
# of large flat polygons").
# Usage: scripts/gen-hall.py OUT.obj [TORUS_SEGMENTS]   (default 400: 284,632 triangles;
#        560: 438,232). Camera of the figures: --eye 100,200,500 --target 1000,90,500 --fov 60
import math, sys
V=[]; F=[]
def vert(p): V.append(p); return len(V)
def quad(a,b,c,d): F.append((a,b,c)); F.append((a,c,d))
def box(x0,y0,z0,x1,y1,z1,n=1):
    # each face split into n x n quads
    def face(o,u,v):
        idx=[[vert((o[0]+u[0]*i/n+v[0]*j/n,o[1]+u[1]*i/n+v[1]*j/n,o[2]+u[2]*i/n+v[2]*j/n)) for j in range(n+1)] for i in range(n+1)]
        for i in range(n):
            for j in range(n): quad(idx[i][j],idx[i+1][j],idx[i+1][j+1],idx[i][j+1])
    dx,dy,dz=x1-x0,y1-y0,z1-z0
    face((x0,y0,z0),(dx,0,0),(0,0,dz)); face((x0,y1,z0),(0,0,dz),(dx,0,0))
    face((x0,y0,z0),(0,dy,0),(dx,0,0)); face((x0,y0,z1),(dx,0,0),(0,dy,0))
    face((x0,y0,z0),(0,0,dz),(0,dy,0)); face((x1,y0,z0),(0,dy,0),(0,0,dz))
def torus(cx,cy,cz,R,r,nu,nv):
    base=len(V)
    for i in range(nu):
        u=2*math.pi*i/nu
        for j in range(nv):
            v=2*math.pi*j/nv
            vert((cx+(R+r*math.cos(v))*math.cos(u),cy+r*math.sin(v),cz+(R+r*math.cos(v))*math.sin(u)))
    for i in range(nu):
        for j in range(nv):
            a=base+1+i*nv+j; b=base+1+((i+1)%nu)*nv+j
            c=base+1+((i+1)%nu)*nv+(j+1)%nv; d=base+1+i*nv+(j+1)%nv
            quad(a,b,c,d)
L,H,W=1500.0,400.0,1000.0
dense=int(sys.argv[2]) if len(sys.argv)>2 else 400
# hall: floor, ceiling, walls: 2 triangles each
box(0,0,0,L,H,W,1)
# columns along two rows
for i in range(8):
    for z in (150.0,850.0): box(100+i*185,0,z,120+i*185,H,z+20,1)
# table
box(450,70,400,1050,80,600,1)
# chairs: 24 around the table, each legs + seat + back tessellated (small triangles)
k=0
for side in (370.0,610.0):
    for i in range(12):
        x=460+i*50; z=side
        for lx in (0,16):
            for lz in (0,16): box(x+lx,0,z+lz,x+lx+2,45,z+lz+2,6)
        box(x,45,z,x+18,50,z+18,12)
        box(x,50,z+(0 if side<400 else 16),x+18,95,z+(2 if side<400 else 18),12)
# one dense ornament on the table: a torus
torus(750,100,500,15,5,dense,dense//2)
with open(sys.argv[1],'w') as f:
    for p in V: f.write('v %.4f %.4f %.4f\n'%p)
    for t in F: f.write('f %d %d %d\n'%t)
print(len(V),'vertices',len(F),'triangles')
